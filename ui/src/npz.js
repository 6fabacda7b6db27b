// NumPy .npy and .npz readers (the candidate NPZ of CONTRACT.md, "Candidate export"): a zip of .npy members, stored
// or deflate-compressed (graspgen writes ISA-L deflate with zip64 records); fflate inflates them.
import { unzipSync } from 'fflate';

const DTYPES = {
  '<f8': Float64Array,
  '<f4': Float32Array,
  '<i8': BigInt64Array,
  '<u8': BigUint64Array,
  '<i4': Int32Array,
  '<u4': Uint32Array,
  '<i2': Int16Array,
  '<u2': Uint16Array,
  '|i1': Int8Array,
  '|u1': Uint8Array,
  '|b1': Uint8Array,
};

/** One .npy array: `{dtype, shape, data}`, `data` a typed array of the C-order elements (a copy, aligned). */
export function parseNpy(bytes) {
  if (bytes.length < 10 || bytes[0] !== 0x93 || String.fromCharCode(...bytes.subarray(1, 6)) !== 'NUMPY') {
    throw new Error('not a .npy array (bad magic)');
  }
  const major = bytes[6];
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const headerLength = major === 1 ? view.getUint16(8, true) : view.getUint32(8, true);
  const start = major === 1 ? 10 : 12;
  const header = new TextDecoder('latin1').decode(bytes.subarray(start, start + headerLength));
  const descr = /'descr':\s*'([^']+)'/.exec(header)?.[1];
  const fortran = /'fortran_order':\s*(True|False)/.exec(header)?.[1];
  const shapeText = /'shape':\s*\(([^)]*)\)/.exec(header)?.[1];
  if (descr === undefined || fortran === undefined || shapeText === undefined) {
    throw new Error(`unreadable .npy header: ${header.trim()}`);
  }
  if (fortran === 'True') throw new Error('Fortran-ordered arrays are not supported');
  const Type = DTYPES[descr];
  if (!Type) throw new Error(`unsupported dtype ${descr}`);
  const shape = shapeText
    .split(',')
    .map((s) => s.trim())
    .filter((s) => s !== '')
    .map(Number);
  const count = shape.reduce((a, b) => a * b, 1);
  const offset = start + headerLength;
  const length = count * Type.BYTES_PER_ELEMENT;
  if (offset + length > bytes.length) throw new Error(`truncated .npy: ${count} elements of ${descr} do not fit`);
  // slice() copies into a fresh, aligned buffer: members start at any offset inside the zip
  const data = new Type(bytes.slice(offset, offset + length).buffer);
  return { dtype: descr, shape, data };
}

/**
 * The arrays of an .npz (ArrayBuffer or Uint8Array): name (without `.npy`) -> parsed array. `names` limits which
 * members are inflated at all (the candidate NPZ of 100,000 pairs holds ~20 MB; a view needs a few of them).
 */
export function readNpz(buffer, names = null) {
  const bytes = buffer instanceof Uint8Array ? buffer : new Uint8Array(buffer);
  const wanted = names ? new Set(names.map((n) => `${n}.npy`)) : null;
  const files = unzipSync(bytes, { filter: (f) => f.name.endsWith('.npy') && (!wanted || wanted.has(f.name)) });
  const out = {};
  for (const [name, member] of Object.entries(files)) out[name.slice(0, -4)] = parseNpy(member);
  return out;
}
