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

  // a scene field's SI unit -> [the unit shown, factor]: what the scene form and the Runs
  // table show a scene's values in (a unit not here is shown as the schema gives it; "1",
  // dimensionless, as a bare number)
  const SCENE = { m: ["mm", 1e3], Pa: ["MPa", 1e-6], N: ["kN", 1e-3], "N/m": ["N/mm", 1e-3],
                  "m/s": ["mm/s", 1e3], "m/s^2": ["m/s²", 1], "kg/m^3": ["kg/m³", 1] };

  function sceneUnit(unit) {
    return (unit && SCENE[unit]) || [unit === "1" ? "" : unit || "", 1];
  }

  function sceneValue(v, unit) {
    // a scene value (SI) in the unit shown, labelled: 0.0005 m -> "0.5 mm"; numbers in a
    // list each; anything else as it is
    const [shownUnit, f] = sceneUnit(unit);
    const scale = (x) => (typeof x === "number" ? +(x * f).toPrecision(12) : x);
    if (typeof v !== "number" && !Array.isArray(v)) return String(v);
    const text = Array.isArray(v) ? `[${v.map(scale).join(", ")}]` : String(scale(v));
    return shownUnit ? `${text} ${shownUnit}` : text;
  }

  return { num, withUnit, duration, sceneUnit, sceneValue };
})();
