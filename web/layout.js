// The 3-D view over the whole window and back (the button, or Esc).
"use strict";
const Layout = (() => {
  function setFull(on) {
    document.body.classList.toggle("viewer-full", on);
    const b = document.getElementById("full-window");
    b.setAttribute("aria-pressed", String(on));
    b.textContent = on ? "Leave full window" : "Full window";
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
