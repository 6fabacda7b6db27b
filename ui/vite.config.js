// Builds the review page into services/api/ui/ (shipped in the wheel, served at /ui/ by graspgen serve).
// Relative asset URLs (base './') so the page works under any mount point; file names carry content hashes.
import { defineConfig } from 'vite';

export default defineConfig({
  base: './',
  build: {
    outDir: process.env.GRASPGEN_UI_OUT ?? '../services/api/ui',
    emptyOutDir: true,
    target: 'es2022',
    sourcemap: false,
    chunkSizeWarningLimit: 1200,
    modulePreload: { polyfill: false },
  },
});
