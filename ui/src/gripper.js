// The gripper's geometry in the grasp frame (CONTRACT.md "Gripper spec", "Gripper geometry from CAD", "Suction
// cups"), as plain data: each part is a shape and its pose T (4x4, row-major nested arrays, metres) in the grasp
// frame. The viewer turns parts into three.js meshes; the tests check them against the contract by hand.

export const UNIT_SCALE = { mm: 0.001, cm: 0.01, m: 1, in: 0.0254 };

export function gripperKind(spec) {
  if (spec.kind === 'suction') return 'suction';
  return spec.geometry ? 'mesh' : 'box';
}

export function translation(x, y, z) {
  return [
    [1, 0, 0, x],
    [0, 1, 0, y],
    [0, 0, 1, z],
    [0, 0, 0, 1],
  ];
}

export function matmul(a, b) {
  const out = [];
  for (let i = 0; i < 4; i++) {
    out.push([0, 1, 2, 3].map((j) => a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] + a[i][3] * b[3][j]));
  }
  return out;
}

export function scaling(s) {
  return [
    [s, 0, 0, 0],
    [0, s, 0, 0],
    [0, 0, s, 0],
    [0, 0, 0, 1],
  ];
}

/** Rotation by `deg` about the local +X (`axis` 'x') or +Z ('z') as a 4x4. */
export function rotation(axis, deg) {
  const r = (deg * Math.PI) / 180;
  const c = Math.cos(r);
  const s = Math.sin(r);
  if (axis === 'x') {
    return [
      [1, 0, 0, 0],
      [0, c, -s, 0],
      [0, s, c, 0],
      [0, 0, 0, 1],
    ];
  }
  return [
    [c, -s, 0, 0],
    [s, c, 0, 0],
    [0, 0, 1, 0],
    [0, 0, 0, 1],
  ];
}

function meshScale(geometry) {
  const s = UNIT_SCALE[geometry?.units];
  if (s === undefined) throw new Error(`gripper geometry has unknown units ${JSON.stringify(geometry?.units)}`);
  return s;
}

/**
 * Parts of `spec` at closing width `width` (metres), in the grasp frame.
 * - box: `{shape: 'box', role, size: [x, y, z], T}` centred at T's origin;
 * - mesh: `{shape: 'mesh', role, path, T}` with the unit scale inside T (T maps the file's coordinates);
 * - cylinder / frustum: `{shape, role, radiusTop, radiusBottom, height, T}`, axis along T's +Z, centred at its
 *   origin, `radiusTop` at +Z.
 */
export function gripperParts(spec, width = 0) {
  const kind = gripperKind(spec);
  const w = Number.isFinite(width) ? width : 0;
  if (kind === 'box') {
    const t = spec.finger_thickness;
    const fw = spec.finger_width;
    const fd = spec.finger_depth;
    const parts = [
      { shape: 'box', role: 'finger', size: [t, fw, fd], T: translation(w / 2 + t / 2, 0, 0) },
      { shape: 'box', role: 'finger_left', size: [t, fw, fd], T: translation(-(w / 2 + t / 2), 0, 0) },
    ];
    const pd = spec.palm_depth ?? 0;
    if (pd > 0) {
      const span = spec.stroke + 2 * t; // x in [-(stroke/2 + t), +(stroke/2 + t)]
      const pw = spec.palm_width ?? fw;
      parts.push({ shape: 'box', role: 'palm', size: [span, pw, pd], T: translation(0, 0, -fd / 2 - pd / 2) });
    }
    return parts;
  }
  if (kind === 'mesh') {
    const g = spec.geometry;
    const S = scaling(meshScale(g));
    const parts = [
      { shape: 'mesh', role: 'finger', path: g.finger, T: matmul(translation(w / 2, 0, 0), S) },
      {
        shape: 'mesh',
        role: 'finger_left',
        path: g.finger_left ?? g.finger,
        T: matmul(matmul(translation(-w / 2, 0, 0), rotation('z', 180)), S),
      },
    ];
    if (g.body) parts.push({ shape: 'mesh', role: 'body', path: g.body, T: S });
    return parts;
  }
  // suction: the cup from its lip at the contact (z = 0) back along -Z, then the tool behind it
  const r = spec.cup_radius;
  const h = spec.cup_height;
  const tool = spec.tool ?? {};
  const base = Math.min(tool.radius ?? r * 0.6, r * 0.6);
  const parts = [
    { shape: 'frustum', role: 'cup', radiusTop: r, radiusBottom: base, height: h, T: translation(0, 0, -h / 2) },
  ];
  const body = tool.geometry ?? spec.geometry;
  if (body?.body) {
    parts.push({ shape: 'mesh', role: 'body', path: body.body, T: scaling(meshScale(body)) });
  } else if (tool.radius > 0 && tool.length > 0) {
    parts.push({
      shape: 'cylinder',
      role: 'tool',
      radiusTop: tool.radius,
      radiusBottom: tool.radius,
      height: tool.length,
      T: translation(0, 0, -h - tool.length / 2),
    });
  }
  return parts;
}

/** The axis a grasp's free rolls turn about: +X for jaws (the closing axis), +Z for a suction cup (its axis). */
export function rollAxis(spec) {
  return gripperKind(spec) === 'suction' ? 'z' : 'x';
}

/** The grasp's pose at another free roll: T(psi) = T(roll_deg) @ R(psi - roll_deg) about the roll axis. */
export function poseAtRoll(pose, rollDeg, psiDeg, axis = 'x') {
  return matmul(pose, rotation(axis, psiDeg - rollDeg));
}

/** Quaternion [x, y, z, w] (w >= 0) of a 4x4's rotation block. */
export function quaternionXyzw(T) {
  const [[m00, m01, m02], [m10, m11, m12], [m20, m21, m22]] = T;
  const trace = m00 + m11 + m22;
  let x;
  let y;
  let z;
  let w;
  if (trace > 0) {
    const s = Math.sqrt(trace + 1) * 2;
    w = s / 4;
    x = (m21 - m12) / s;
    y = (m02 - m20) / s;
    z = (m10 - m01) / s;
  } else if (m00 > m11 && m00 > m22) {
    const s = Math.sqrt(1 + m00 - m11 - m22) * 2;
    w = (m21 - m12) / s;
    x = s / 4;
    y = (m01 + m10) / s;
    z = (m02 + m20) / s;
  } else if (m11 > m22) {
    const s = Math.sqrt(1 + m11 - m00 - m22) * 2;
    w = (m02 - m20) / s;
    x = (m01 + m10) / s;
    y = s / 4;
    z = (m12 + m21) / s;
  } else {
    const s = Math.sqrt(1 + m22 - m00 - m11) * 2;
    w = (m10 - m01) / s;
    x = (m02 + m20) / s;
    y = (m12 + m21) / s;
    z = s / 4;
  }
  const sign = w < 0 ? -1 : 1;
  return [x * sign, y * sign, z * sign, w * sign];
}

/** Every file path a spec's geometry names (to fetch from GET /v1/grippers/{name}/versions/{v}/files/{path}). */
export function meshPaths(spec) {
  return [...new Set(gripperParts(spec, 0).filter((p) => p.shape === 'mesh').map((p) => p.path))];
}
