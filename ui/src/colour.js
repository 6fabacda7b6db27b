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
