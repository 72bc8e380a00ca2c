// Numbers as an engineer reads them: a few significant digits, their unit, durations in
// minutes and seconds. The server sends display values (kN, mm, %) with their units.
"use strict";
const Units = (() => {
  function num(v, digits = 3) {
    if (v === null || v === undefined || !Number.isFinite(+v)) return "–";
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e5 || a < 1e-3)) return (+v).toExponential(digits - 1);
    return String(+(+v).toPrecision(digits));
  }

  function withUnit(v, unit, digits = 3) {
    const text = Array.isArray(v) ? `(${v.map((c) => num(c, digits)).join(", ")})`
                                  : num(v, digits);
    return unit ? `${text} ${unit}` : text;
  }

  function duration(s) {
    if (s === null || s === undefined || !Number.isFinite(s)) return "–";
    if (s < 1) return "under 1 s";
    s = Math.round(s);
    if (s < 60) return `${s} s`;
    const m = Math.floor(s / 60);
    if (m < 60) return `${m} min ${String(s % 60).padStart(2, "0")} s`;
    return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
  }

  return { num, withUnit, duration };
})();
