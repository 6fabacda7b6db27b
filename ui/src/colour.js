// Colour scales for margins: a perceptually ordered ramp (viridis' anchor colours) from the set's smallest to its
// largest value, so a glance tells the weak grasps (dark) from the strong ones (yellow).

const RAMP = [
  [0.267, 0.005, 0.329],
  [0.283, 0.141, 0.458],
  [0.254, 0.265, 0.53],
  [0.207, 0.372, 0.553],
  [0.164, 0.471, 0.558],
  [0.128, 0.567, 0.551],
  [0.135, 0.659, 0.518],
  [0.267, 0.749, 0.441],
  [0.478, 0.821, 0.318],
  [0.741, 0.873, 0.15],
  [0.993, 0.906, 0.144],
];

/** [r, g, b] in 0..1 for t in 0..1 (clamped). */
export function ramp(t) {
  const x = Math.min(1, Math.max(0, Number.isFinite(t) ? t : 0)) * (RAMP.length - 1);
  const i = Math.min(RAMP.length - 2, Math.floor(x));
  const f = x - i;
  return [0, 1, 2].map((k) => RAMP[i][k] + (RAMP[i + 1][k] - RAMP[i][k]) * f);
}

/** An sRGB component (0..1) in linear light (IEC 61966-2-1), as three.js' colour management converts it. */
export function srgbToLinear(c) {
  return c < 0.04045 ? c * 0.0773993808 : Math.pow(c * 0.9478672986 + 0.0521327014, 2.4);
}

const LUT_STEPS = 1024;
let linearLut = null;

/**
 * Linear-light colours (k*3 floats, what three.js vertex colours hold) of `values` on the ramp over `r`; `grey`
 * (sRGB) where `values` is null. A table of the ramp in 1024 steps: a cloud of 50,000 candidates takes ~1 ms.
 */
export function linearRampColours(values, r, k, grey = [0.45, 0.45, 0.5]) {
  if (linearLut === null) {
    linearLut = new Float32Array(LUT_STEPS * 3);
    for (let i = 0; i < LUT_STEPS; i++) {
      ramp(i / (LUT_STEPS - 1)).forEach((c, j) => (linearLut[i * 3 + j] = srgbToLinear(c)));
    }
  }
  const out = new Float32Array(k * 3);
  const fill = grey.map(srgbToLinear);
  for (let i = 0; i < k; i++) {
    if (values) {
      const at = Math.round(Math.min(1, Math.max(0, normalise(values[i], r))) * (LUT_STEPS - 1)) * 3;
      out[i * 3] = linearLut[at];
      out[i * 3 + 1] = linearLut[at + 1];
      out[i * 3 + 2] = linearLut[at + 2];
    } else {
      out.set(fill, i * 3);
    }
  }
  return out;
}

export function cssColour([r, g, b]) {
  return `rgb(${Math.round(r * 255)}, ${Math.round(g * 255)}, ${Math.round(b * 255)})`;
}

/** The measures a set can be coloured by, with each grasp's value (null where a grasp lacks it). */
export const MEASURES = {
  friction_margin_deg: { label: 'friction margin (deg)', of: (g) => g.friction_margin_deg ?? null },
  hold_margin: { label: 'hold margin (x load)', of: (g) => g.hold_margin ?? null },
  quality: { label: 'quality score', of: (g) => g.quality?.score ?? null },
};

/** {min, max} of finite values, or null when there is none. */
export function range(values) {
  let min = Infinity;
  let max = -Infinity;
  for (const v of values) {
    if (v === null || !Number.isFinite(v)) continue;
    if (v < min) min = v;
    if (v > max) max = v;
  }
  return min <= max ? { min, max } : null;
}

export function normalise(v, r) {
  if (v === null || !r || !Number.isFinite(v)) return 0;
  return r.max > r.min ? (v - r.min) / (r.max - r.min) : 1;
}
