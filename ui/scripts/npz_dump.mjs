// Prints each member of an NPZ as the page reads it: {name: {dtype, shape, values}} (tests/ui/test_build.py
// compares it with NumPy's reading of the same file). `--reader native` uses readNpzAsync (DecompressionStream and
// the page's own zip directory reader), the default readNpz (fflate).
import { readFileSync } from 'node:fs';
import { readNpz, readNpzAsync } from '../src/npz.js';

const native = process.argv.includes('--reader') && process.argv[process.argv.indexOf('--reader') + 1] === 'native';
const bytes = readFileSync(process.argv[2]);
const arrays = native ? await readNpzAsync(bytes) : readNpz(bytes);
const out = {};
for (const [name, a] of Object.entries(arrays)) {
  out[name] = { dtype: a.dtype, shape: a.shape, values: Array.from(a.data, (v) => (typeof v === 'bigint' ? Number(v) : v)) };
}
process.stdout.write(JSON.stringify(out));
