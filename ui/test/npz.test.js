// The NPZ reader on hand-made arrays: stored and deflated members, dtypes, the member filter, refusals.
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { zipSync } from 'fflate';
import { parseNpy, readNpz, readNpzAsync, zipMembers } from '../src/npz.js';

/** A version-1 .npy of `typed` (a typed array) with the header NumPy writes. */
function npy(descr, shape, typed, fortran = false) {
  const dict = `{'descr': '${descr}', 'fortran_order': ${fortran ? 'True' : 'False'}, 'shape': (${shape.join(', ')}${shape.length === 1 ? ',' : ''}), }`;
  let header = dict;
  while ((10 + header.length + 1) % 64) header += ' ';
  header += '\n';
  const bytes = new Uint8Array(10 + header.length + typed.byteLength);
  bytes.set([0x93, ...new TextEncoder().encode('NUMPY'), 1, 0, header.length & 0xff, header.length >> 8]);
  bytes.set(new TextEncoder().encode(header), 10);
  bytes.set(new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength), 10 + header.length);
  return bytes;
}

const midpoints = new Float64Array([0.001, 0.002, 0.003, -0.5, 0.25, 1e-9]);
const medoids = new BigInt64Array([3n, 0n]);
const free = new Uint8Array([1, 0, 0, 1]);
const labels = new Int32Array([0, 1, 1, 0]);

for (const level of [0, 6]) {
  test(`readNpz reads ${level ? 'deflated' : 'stored'} members`, () => {
    const zip = zipSync(
      {
        'midpoints.npy': npy('<f8', [2, 3], midpoints),
        'medoids.npy': npy('<i8', [2], medoids),
        'free_rolls.npy': npy('|b1', [2, 2], free),
        'labels.npy': npy('<i4', [2, 2], labels),
      },
      { level },
    );
    const all = readNpz(zip.buffer);
    assert.deepEqual(Object.keys(all).sort(), ['free_rolls', 'labels', 'medoids', 'midpoints']);
    assert.deepEqual(all.midpoints.shape, [2, 3]);
    assert.deepEqual([...all.midpoints.data], [...midpoints]);
    assert.deepEqual([...all.medoids.data], [3n, 0n]);
    assert.deepEqual(all.free_rolls.shape, [2, 2]);
    assert.deepEqual([...all.free_rolls.data], [1, 0, 0, 1]);
    assert.deepEqual([...all.labels.data], [0, 1, 1, 0]);
    const some = readNpz(zip, ['midpoints']);
    assert.deepEqual(Object.keys(some), ['midpoints']);
  });

  test(`readNpzAsync (native inflater) reads ${level ? 'deflated' : 'stored'} members as readNpz does`, async () => {
    const zip = zipSync(
      { 'midpoints.npy': npy('<f8', [2, 3], midpoints), 'medoids.npy': npy('<i8', [2], medoids), 'x.txt': new Uint8Array(3) },
      { level },
    );
    const members = zipMembers(zip);
    assert.deepEqual(Object.keys(members).sort(), ['medoids.npy', 'midpoints.npy', 'x.txt']);
    assert.equal(members['midpoints.npy'].method, level ? 8 : 0);
    const all = await readNpzAsync(zip);
    assert.deepEqual(Object.keys(all).sort(), ['medoids', 'midpoints']);
    assert.deepEqual([...all.midpoints.data], [...midpoints]);
    assert.deepEqual([...all.medoids.data], [3n, 0n]);
    assert.deepEqual(Object.keys(await readNpzAsync(zip.buffer, ['medoids'])), ['medoids']);
  });
}

test('zipMembers refuses what is not a zip', () => {
  assert.throws(() => zipMembers(new Uint8Array(100)), /not a zip/);
});

test('parseNpy refuses what it cannot read', () => {
  assert.throws(() => parseNpy(new Uint8Array([1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11])), /magic/);
  assert.throws(() => parseNpy(npy('<f8', [2], new Float64Array(2), true)), /Fortran/);
  assert.throws(() => parseNpy(npy('<c16', [1], new Float64Array(2))), /dtype/);
  assert.throws(() => parseNpy(npy('<f8', [3], new Float64Array(2))), /truncated/);
  const scalar = parseNpy(npy('<f8', [], new Float64Array([2.5])));
  assert.deepEqual(scalar.shape, []);
  assert.equal(scalar.data[0], 2.5);
});
