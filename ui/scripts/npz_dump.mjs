// Prints each member of an NPZ as the page reads it: {name: {dtype, shape, values}} (tests/ui/test_build.py
// compares it with NumPy's reading of the same file).
import { readFileSync } from 'node:fs';
import { readNpz } from '../src/npz.js';

const arrays = readNpz(readFileSync(process.argv[2]));
const out = {};
for (const [name, a] of Object.entries(arrays)) {
  out[name] = { dtype: a.dtype, shape: a.shape, values: Array.from(a.data, (v) => (typeof v === 'bigint' ? Number(v) : v)) };
}
process.stdout.write(JSON.stringify(out));
