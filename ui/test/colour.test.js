// The candidate cloud's colours: the ramp of colour.js in linear light, through a table (linearRampColours).
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { linearRampColours, ramp, srgbToLinear } from '../src/colour.js';

test('srgbToLinear is the sRGB transfer function (IEC 61966-2-1)', () => {
  assert.equal(srgbToLinear(0), 0);
  assert.ok(Math.abs(srgbToLinear(1) - 1) < 1e-9);
  assert.ok(Math.abs(srgbToLinear(0.04) - 0.04 / 12.92) < 1e-9); // the linear segment
  assert.ok(Math.abs(srgbToLinear(0.5) - ((0.5 + 0.055) / 1.055) ** 2.4) < 1e-9);
});

test('the ends and the middle of the range get the ramp colours in linear light', () => {
  const r = { min: 2, max: 6 };
  const out = linearRampColours([2, 6, 4, 100, -5], r, 5);
  assert.equal(out.length, 15);
  const want = (t) => ramp(t).map(srgbToLinear);
  const near = (got, exp, tol) => got.every((v, i) => Math.abs(v - exp[i]) < tol);
  assert.ok(near([...out.subarray(0, 3)], want(0), 1e-6));
  assert.ok(near([...out.subarray(3, 6)], want(1), 1e-6));
  assert.ok(near([...out.subarray(6, 9)], want(0.5), 2e-3)); // a table of 1024 steps
  assert.deepEqual([...out.subarray(9, 12)], [...out.subarray(3, 6)]); // clamped above
  assert.deepEqual([...out.subarray(12, 15)], [...out.subarray(0, 3)]); // and below
});

test('without values every candidate is the grey', () => {
  const out = linearRampColours(null, null, 2, [0.5, 0.5, 0.5]);
  const g = srgbToLinear(0.5);
  assert.ok([...out].every((v) => Math.abs(v - g) < 1e-6));
});
