// Prints a part file as the page reads it (src/mesh.js): {points, vertices, triangles, min, max} in metres
// (tests/ui/test_build.py compares it with trimesh's reading of the same file).
import { readFileSync } from 'node:fs';
import { partGeometry } from '../src/mesh.js';

const [file, format, units] = process.argv.slice(2);
const bytes = readFileSync(file);
const buffer = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
const { geometry, points } = await partGeometry(buffer, format, units);
const box = geometry.boundingBox;
const count = geometry.attributes.position.count;
const triangles = points ? 0 : (geometry.index ? geometry.index.count : count) / 3;
process.stdout.write(
  JSON.stringify({ points, vertices: count, triangles, min: box.min.toArray(), max: box.max.toArray() }),
);
