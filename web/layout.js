// The 3-D view over the whole window and back (the button, or Esc).
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

  function init() {
    const b = document.getElementById("full-window");
    b.onclick = () => setFull(!document.body.classList.contains("viewer-full"));
    document.addEventListener("keydown", (ev) => {
      if (ev.key === "Escape" && document.body.classList.contains("viewer-full")) setFull(false);
    });
  }

  return { init, setFull };
})();
