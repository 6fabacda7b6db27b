// The gripper's parts against CONTRACT.md by hand: box fingers and palm, CAD finger frames, suction cup and tool,
// the roll convention, quaternions. Specs are hand-made JSON, as the contract writes them.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { gripperKind, gripperParts, matmul, meshPaths, poseAtRoll, quaternionXyzw } from '../src/gripper.js';

const BOX = {
  name: 'pgn-80', stroke: 0.08, min_width: 0.0, finger_width: 0.02, finger_depth: 0.03, finger_thickness: 0.01,
  palm_depth: 0.02, palm_width: 0.025, friction: 0.5, pregrasp_clearance: 0.02,
};
const CAD = {
  name: 'pgn-80-vgroove', kind: 'parallel', stroke: 0.08, friction: 0.5, pregrasp_clearance: 0.02,
  geometry: { units: 'mm', finger: 'finger.stl', body: 'body.stl', pad: { width: 0.02, depth: 0.012 } },
};
const CUP = {
  name: 'cup-30', kind: 'suction', cup_radius: 0.015, cup_height: 0.02, max_strain: 0.1, vacuum: 60000,
  friction: 0.5, tool: { radius: 0.012, length: 0.12 }, pregrasp_clearance: 0.03,
};

/** A point p (file or shape coordinates) mapped by the 4x4 T. */
function apply(T, p) {
  return [0, 1, 2].map((i) => T[i][0] * p[0] + T[i][1] * p[1] + T[i][2] * p[2] + T[i][3]);
}

function close(a, b, eps = 1e-12) {
  assert.equal(a.length, b.length);
  a.forEach((v, i) => assert.ok(Math.abs(v - b[i]) <= eps, `${JSON.stringify(a)} != ${JSON.stringify(b)}`));
}

test('box fingers: inner faces at +-w/2, centred at y = z = 0; the palm spans the stroke behind them', () => {
  const w = 0.03;
  const [right, left, palm] = gripperParts(BOX, w);
  assert.equal(gripperKind(BOX), 'box');
  close(right.size, [0.01, 0.02, 0.03]);
  close(apply(right.T, [-0.005, 0, 0]), [w / 2, 0, 0]); // the inner face (-t/2 in the box) at +w/2
  close(apply(left.T, [0.005, 0, 0]), [-w / 2, 0, 0]);
  close(palm.size, [0.08 + 2 * 0.01, 0.025, 0.02]);
  close(apply(palm.T, [0, 0, 0.01]), [0, 0, -0.015]); // palm top at z = -finger_depth/2
  close(apply(palm.T, [0, 0, -0.01]), [0, 0, -0.035]);
  assert.equal(gripperParts({ ...BOX, palm_depth: 0 }, w).length, 2, 'palm_depth 0: no palm');
  close(gripperParts({ ...BOX, palm_width: undefined }, w)[2].size, [0.1, 0.02, 0.02]); // default: finger_width
});

test('CAD fingers: the +X finger frame at (+w/2, 0, 0), the -X one turned 180 deg about Z, units applied', () => {
  const w = 0.04;
  const parts = gripperParts(CAD, w);
  assert.equal(gripperKind(CAD), 'mesh');
  const [right, left, body] = parts;
  assert.deepEqual([right.role, right.path, left.role, left.path, body.role, body.path],
    ['finger', 'finger.stl', 'finger_left', 'finger.stl', 'body', 'body.stl']);
  close(apply(right.T, [0, 0, 0]), [w / 2, 0, 0]); // the pad's contact point
  close(apply(right.T, [1, 2, 3]), [w / 2 + 0.001, 0.002, 0.003]); // 1 mm outwards along +X
  close(apply(left.T, [0, 0, 0]), [-w / 2, 0, 0], 1e-15);
  close(apply(left.T, [1, 2, 3]), [-w / 2 - 0.001, -0.002, 0.003], 1e-15); // outwards is -X; Z (approach) kept
  close(apply(body.T, [10, 20, -30]), [0.01, 0.02, -0.03]); // the body is in the grasp frame
  const own = gripperParts({ ...CAD, geometry: { ...CAD.geometry, finger_left: 'left.stl', units: 'm' } }, w);
  assert.equal(own[1].path, 'left.stl');
  close(apply(own[1].T, [0.001, 0, 0]), [-w / 2 - 0.001, 0, 0], 1e-15);
  assert.deepEqual(meshPaths(CAD), ['finger.stl', 'body.stl']);
  assert.throws(() => gripperParts({ ...CAD, geometry: { ...CAD.geometry, units: 'furlong' } }, w), /units/);
});

test('suction: the cup from the contact back along -Z, the tool cylinder behind it', () => {
  const [cup, tool] = gripperParts(CUP);
  assert.equal(gripperKind(CUP), 'suction');
  assert.equal(cup.shape, 'frustum');
  assert.equal(cup.radiusTop, 0.015); // the lip, at +Z: the contact
  close(apply(cup.T, [0, 0, cup.height / 2]), [0, 0, 0]);
  close(apply(cup.T, [0, 0, -cup.height / 2]), [0, 0, -0.02]);
  assert.equal(tool.shape, 'cylinder');
  assert.equal(tool.radiusTop, 0.012);
  close(apply(tool.T, [0, 0, tool.height / 2]), [0, 0, -0.02], 1e-15);
  close(apply(tool.T, [0, 0, -tool.height / 2]), [0, 0, -0.14], 1e-15);
  const meshTool = gripperParts({ ...CUP, tool: { geometry: { units: 'mm', body: 'tool.stl' } } });
  assert.equal(meshTool[1].path, 'tool.stl');
  close(apply(meshTool[1].T, [0, 0, -100]), [0, 0, -0.1]);
});

test('free rolls: Y = cos(psi) Y0 + sin(psi) Z0, Z = -sin(psi) Y0 + cos(psi) Z0 about the closing axis', () => {
  const c = Math.SQRT1_2;
  // X = (1, 0, 0), Y0 = (0, c, c), Z0 = (0, -c, c): a pose drawn at roll 0
  const pose = [
    [1, 0, 0, 0.1],
    [0, c, -c, 0.2],
    [0, c, c, 0.3],
    [0, 0, 0, 1],
  ];
  const at = (T) => [0, 1, 2].map((j) => [T[0][j], T[1][j], T[2][j]]);
  for (const psi of [22.5, 90, 180, 337.5]) {
    const r = (psi * Math.PI) / 180;
    const [X, Y, Z] = at(poseAtRoll(pose, 0, psi));
    const [X0, Y0, Z0] = at(pose);
    close(X, X0, 1e-12);
    close(Y, Y0.map((v, i) => Math.cos(r) * v + Math.sin(r) * Z0[i]), 1e-12);
    close(Z, Y0.map((v, i) => -Math.sin(r) * v + Math.cos(r) * Z0[i]), 1e-12);
  }
  // from a pose drawn at 90 deg, the roll 90 is the pose itself and 0 the one above
  const at90 = poseAtRoll(pose, 0, 90);
  close(poseAtRoll(at90, 90, 0).flat(), pose.flat(), 1e-12);
  close(poseAtRoll(at90, 90, 90).flat(), at90.flat(), 1e-15);
  // a suction grasp rolls about +Z: the axis stays
  const z = poseAtRoll(pose, 0, 45, 'z');
  close([z[0][2], z[1][2], z[2][2]], [0, -c, c], 1e-12);
});

test('quaternion xyzw with w >= 0', () => {
  const I = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]];
  close(quaternionXyzw(I), [0, 0, 0, 1]);
  close(quaternionXyzw([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]), [1, 0, 0, 0]);
  const s = Math.SQRT1_2;
  close(quaternionXyzw([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), [0, 0, s, s], 1e-15);
  // -90 deg about Y (trace < 0 branch not needed): q = (0, -s, 0, s)
  close(quaternionXyzw([[0, 0, -1, 0], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]]), [0, -s, 0, s], 1e-15);
  const q = quaternionXyzw([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]); // 180 deg about (0, 1, 1)
  assert.ok(q[3] >= 0);
  close(q, [0, s, s, 0], 1e-15);
  close(matmul(I, I).flat(), I.flat());
});
