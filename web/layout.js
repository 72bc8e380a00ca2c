// The 3-D view over the whole window and back (the button, or Esc), and the headline's height
// over it: whole rows of the summary's cards.
"use strict";
const Layout = (() => {
  function setFull(on) {
    document.body.classList.toggle("viewer-full", on);
    const b = document.getElementById("full-window");
    b.setAttribute("aria-pressed", String(on));
    b.textContent = on ? "Leave full window" : "Full window";
    // the 3-D view is another page (viser's, on its own port): while it has the keyboard
    // its keys do not reach this one, so Esc leaves only once the page has it back
    b.title = on ? "back to the page (Esc too, unless the 3-D view has the keyboard: click " +
                   "this button then)" : "the 3-D view over the whole window (Esc leaves)";
  }

  function fitHeadline() {
    // the headline ends under a whole row of the summary's cards, not through one (a review
    // saw a row of values cut in half by the 3-D view); the 3-D view takes what is left, and
    // a line under the headline says how many cards are below it
    const h = document.getElementById("headline"), more = document.getElementById("summary-more");
    const summary = document.getElementById("summary");
    h.style.maxHeight = h.style.minHeight = "";
    summary.classList.remove("tight");
    const cards = [...summary.querySelectorAll(".quantity")];
    if (!cards.length || h.scrollHeight <= h.clientHeight + 1) {
      more.hidden = true;
      counted = null;
      return;
    }
    more.hidden = false;  // its line comes out of the headline's room: measured with it
    const top = h.getBoundingClientRect().top - h.scrollTop, room = h.clientHeight;
    let bottoms = cards.map((c) => c.getBoundingClientRect().bottom - top);
    if (!bottoms.some((b) => b <= room + 0.5)) {
      // not one whole row (1280 x 720 with a line above the cards): the cards without their
      // "at ..." lines, which their tooltips keep
      summary.classList.add("tight");
      bottoms = cards.map((c) => c.getBoundingClientRect().bottom - top);
    }
    const fits = bottoms.filter((b) => b <= room + 0.5);
    const end = fits.length ? Math.max(...fits) : 0;
    // max-height is of the content box: the paddings add to it (the next row starts a gap of
    // about 4 px below)
    const css = getComputedStyle(h);
    const pad = parseFloat(css.paddingTop) + parseFloat(css.paddingBottom);
    // (under its least height too, which is a row's of cards with their "at" lines)
    if (end) {
      h.style.maxHeight = h.style.minHeight = `${Math.floor(Math.min(end + 2, room) - pad)}px`;
    }
    counted = { h, more, cards };
    countBelow();
  }

  let counted = null;  // the headline's cards, as last fitted
  function countBelow() {
    // the cards under the headline's bottom as it is scrolled now (a review saw "11 more"
    // stay after a click had shown four of them)
    if (!counted) return;
    const { h, more, cards } = counted;
    const bottom = h.getBoundingClientRect().bottom;
    const below = cards.filter((c) => c.isConnected &&
                               c.getBoundingClientRect().bottom > bottom + 0.5);
    more.hidden = !below.length;
    more.textContent = `▾ ${below.length} more result${below.length === 1 ? "" : "s"} ` +
      "below: scroll the cards";
    more.onclick = () => below[0] && below[0].scrollIntoView({ block: "nearest" });
  }

  let fitting = false;
  function fitSoon() {
    // once per frame, after the layout the change made
    if (fitting) return;
    fitting = true;
    requestAnimationFrame(() => { fitting = false; fitHeadline(); });
  }

  function init() {
    // the window's size and the headline's contents (cards drawn, a line added) change it
    new ResizeObserver(fitSoon).observe(document.getElementById("centre"));
    document.getElementById("headline").addEventListener("scroll", countBelow,
                                                         { passive: true });
    new MutationObserver(fitSoon).observe(document.getElementById("headline"),
                                          { childList: true, subtree: true, attributes: true,
                                            attributeFilter: ["hidden"] });
    const b = document.getElementById("full-window");
    b.onclick = () => setFull(!document.body.classList.contains("viewer-full"));
    document.addEventListener("keydown", (ev) => {
      if (ev.key === "Escape" && document.body.classList.contains("viewer-full")) setFull(false);
    });
  }

  return { init, setFull };
})();
