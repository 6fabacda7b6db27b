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
  const data = new Type(Uint8Array.prototype.slice.call(bytes, offset, offset + length).buffer); // a Buffer's own slice() is a view
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

/** Where each member's data lies in a zip: name -> {method, offset, size} (zip64 records included). */
export function zipMembers(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let eocd = -1;
  for (let i = bytes.length - 22; i >= Math.max(0, bytes.length - 65557); i--) {
    if (view.getUint32(i, true) === 0x06054b50) {
      eocd = i;
      break;
    }
  }
  if (eocd < 0) throw new Error('not a zip file (no end of central directory)');
  let count = view.getUint16(eocd + 10, true);
  let dirOffset = view.getUint32(eocd + 16, true);
  const locator = eocd - 20;
  if (locator >= 0 && view.getUint32(locator, true) === 0x07064b50) {
    const zip64 = Number(view.getBigUint64(locator + 8, true));
    if (view.getUint32(zip64, true) !== 0x06064b50) throw new Error('bad zip64 end of central directory');
    count = Number(view.getBigUint64(zip64 + 32, true));
    dirOffset = Number(view.getBigUint64(zip64 + 48, true));
  }
  const members = {};
  let p = dirOffset;
  for (let k = 0; k < count; k++) {
    if (view.getUint32(p, true) !== 0x02014b50) throw new Error('bad zip central directory entry');
    const method = view.getUint16(p + 10, true);
    let size = view.getUint32(p + 20, true);
    let uncompressed = view.getUint32(p + 24, true);
    const nameLength = view.getUint16(p + 28, true);
    const extraLength = view.getUint16(p + 30, true);
    const commentLength = view.getUint16(p + 32, true);
    let local = view.getUint32(p + 42, true);
    const name = new TextDecoder().decode(bytes.subarray(p + 46, p + 46 + nameLength));
    // zip64 extra field: the 64-bit values of those that are 0xFFFFFFFF, in this order
    for (let e = p + 46 + nameLength; e < p + 46 + nameLength + extraLength; ) {
      const id = view.getUint16(e, true);
      const len = view.getUint16(e + 2, true);
      if (id === 0x0001) {
        let q = e + 4;
        if (uncompressed === 0xffffffff) (uncompressed = Number(view.getBigUint64(q, true))), (q += 8);
        if (size === 0xffffffff) (size = Number(view.getBigUint64(q, true))), (q += 8);
        if (local === 0xffffffff) local = Number(view.getBigUint64(q, true));
      }
      e += 4 + len;
    }
    if (view.getUint32(local, true) !== 0x04034b50) throw new Error(`bad zip local header of ${name}`);
    const offset = local + 30 + view.getUint16(local + 26, true) + view.getUint16(local + 28, true);
    members[name] = { method, offset, size, uncompressed };
    p += 46 + nameLength + extraLength + commentLength;
  }
  return members;
}

async function inflateRaw(data) {
  const stream = new Blob([data]).stream().pipeThrough(new DecompressionStream('deflate-raw'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/**
 * As readNpz, with the browser's own inflater (DecompressionStream, native code: several times faster than
 * JavaScript on 20 MB of candidates) where it has one, members in parallel; fflate otherwise.
 */
export async function readNpzAsync(buffer, names = null) {
  if (typeof DecompressionStream === 'undefined') return readNpz(buffer, names);
  const bytes = buffer instanceof Uint8Array ? buffer : new Uint8Array(buffer);
  const members = zipMembers(bytes);
  const wanted = Object.keys(members).filter(
    (n) => n.endsWith('.npy') && (!names || names.includes(n.slice(0, -4))),
  );
  const out = {};
  await Promise.all(
    wanted.map(async (name) => {
      const { method, offset, size } = members[name];
      const data = bytes.subarray(offset, offset + size);
      if (method !== 0 && method !== 8) throw new Error(`${name}: unsupported zip compression method ${method}`);
      out[name.slice(0, -4)] = parseNpy(method === 0 ? data : await inflateRaw(data));
    }),
  );
  return out;
}
