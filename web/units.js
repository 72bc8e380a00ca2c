// Numbers as an engineer reads them: a few significant digits, their unit, durations in
// minutes and seconds. The server sends display values (kN, mm, %) with their units.
"use strict";
const Units = (() => {
  function num(v, digits = 3) {
    if (v === null || v === undefined || !Number.isFinite(+v)) return "–";
    const a = Math.abs(v);
    // a count (elements, DoFs, iterations) whole: 8004 DoFs are not "8000"
    if (Number.isInteger(+v) && a < 1e9) return (a === 0 ? 0 : +v).toLocaleString("en-US");
    // written out, never with an exponent ("0.0000314 mm", "123000 mm", not "3.14e-5 mm")
    return (+v).toLocaleString("en-US", { maximumSignificantDigits: digits,
                                           useGrouping: false });
  }

  function withUnit(v, unit, digits = 3) {
    // a point's coordinate within round-off of zero beside the others is zero: an edge point
    // on the x axis read "(-30, 3.05e-13, 0) mm"
    const size = Array.isArray(v) ? Math.max(...v.map((c) => Math.abs(+c) || 0)) : 0;
    const text = Array.isArray(v)
      ? `(${v.map((c) => num(Math.abs(c) <= 1e-9 * size ? 0 : c, digits)).join(", ")})`
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
  // dimensionless, as a bare number). An angle in degrees: a tool's rotation of 1.5708 rad
  // reads as 90.0002 deg at a glance. A thickness gradient (thickness + gradient . X) is
  // thickness per length along the sheet, absolute, not relative to the thickness (so not
  // %/mm): mm of thickness per mm, the same number as m/m.
  const SCENE = { m: ["mm", 1e3], Pa: ["MPa", 1e-6], N: ["kN", 1e-3], "N/m": ["N/mm", 1e-3],
                  "m/s": ["mm/s", 1e3], "m/s^2": ["m/s²", 1], "kg/m^3": ["kg/m³", 1],
                  "m/m": ["mm/mm", 1], rad: ["deg", 180 / Math.PI] };
  // a table's rows of several units (a tool's keyframes [t, dx, dy, dz, rx, ry, rz]): the
  // schema's unit -> each column's [name, SI unit]
  const COLUMNS = { "t, m, rad": [["t", "1"], ["dx", "m"], ["dy", "m"], ["dz", "m"],
                                  ["rx", "rad"], ["ry", "rad"], ["rz", "rad"]] };

  function sceneUnit(unit) {
    if (COLUMNS[unit]) return [[...new Set(COLUMNS[unit].map(([, u]) => sceneUnit(u)[0] || "t"))]
      .join(", "), 1];
    return (unit && SCENE[unit]) || [unit === "1" ? "" : unit || "", 1];
  }

  // a server's message in the units the page shows: "0.1 m is too coarse (at most 0.0266 m)"
  // under a box in mm reads "100 mm ... (at most 26.6 mm)"; a unit with a power (m^2) is left
  // (a number after a space or a bracket; not "m per file unit", a scale's unit)
  const QUANTITY = /(?<=^|[\s(])(-?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?) (m\/s\^2|kg\/m\^3|m\/s|m\/m|N\/m|m|Pa|N|rad)(?![\w^\/²³]| per\b)/g;
  function shownMessage(text) {
    return text.replace(QUANTITY, (all, v, unit) => {
      const [u, f] = SCENE[unit];
      return f === 1 ? all : `${toShown(+v, unit)} ${u}`;
    });
  }

  function columns(unit) {
    return COLUMNS[unit] || null;
  }

  // an SI value in the unit shown, and back: 12 significant digits where the factor is a
  // power of ten (0.0165 m is 16.5 mm, not 16.499999999999996; 16.5 mm is 0.0165 m); an angle
  // at full precision, degrees first divided by 180, so 90 deg is pi/2 to the last bit and
  // pi/2 shows as 90
  const round = (x) => Number(x.toPrecision(12));
  function toShown(v, unit) {
    if (unit === "rad") return round(v / Math.PI * 180);
    return round(v * sceneUnit(unit)[1]);
  }
  function toSI(v, unit) {
    if (unit === "rad") return v / 180 * Math.PI;
    const f = sceneUnit(unit)[1];
    return f === 1 ? v : round(v / f);
  }

  function sceneValue(v, unit) {
    // a scene value (SI) in the unit shown, labelled: 0.0005 m -> "0.5 mm"; numbers in a
    // list each (a table's rows column by column); anything else as it is
    const cols = columns(unit);
    const [shownUnit] = sceneUnit(unit);
    const scale = (x, u = unit) => (typeof x === "number" ? toShown(x, u) : x);
    const row = (r) => (Array.isArray(r) ? `[${r.map((x, i) => scale(x, (cols[i] || [])[1]))
      .join(", ")}]`
                                         : String(r));
    if (typeof v !== "number" && !Array.isArray(v)) return String(v);
    const text = !Array.isArray(v) ? String(scale(v))
      : cols ? `[${v.map(row).join(", ")}]` : `[${v.map((x) => scale(x)).join(", ")}]`;
    return shownUnit ? `${text} ${shownUnit}` : text;
  }

  return { num, withUnit, duration, sceneUnit, columns, toShown, toSI, sceneValue, shownMessage };
})();
