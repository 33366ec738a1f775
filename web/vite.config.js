// The page is built into the Python package (service/static), which the wheel ships, so
// `pip install` needs no node; tests/web/test_static_fresh.py fails when the build is stale.
import { defineConfig } from "vite";

export default defineConfig({
  base: "/",
  build: {
    outDir: "../service/static",
    emptyOutDir: true,
    chunkSizeWarningLimit: 1500,
    sourcemap: false,
    // no hashes: a rebuild from the same sources rewrites the same file names
    rollupOptions: {
      output: {
        entryFileNames: "assets/[name].js",
        chunkFileNames: "assets/[name].js",
        assetFileNames: "assets/[name][extname]",
      },
    },
  },
});
