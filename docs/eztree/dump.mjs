// One ez-tree preset built in Node, its branch and leaf meshes written as JSON (positions,
// normals, uvs, indices) with the preset's options. Textures are not loaded here (Node has
// no image decoder): to_glb.py applies ez-tree's own bark and leaf files from the package.
//   node dump.mjs "Oak Large" oak_large.json
import fs from 'fs';
import * as THREE from 'three';

THREE.TextureLoader.prototype.load = function () {
  return new THREE.Texture();
};
const { Tree } = await import('@dgreenheck/ez-tree');

const [, , preset, out] = process.argv;
const tree = new Tree();
tree.loadPreset(preset);
const meshes = {};
for (const [name, mesh] of [['bark', tree.branchesMesh], ['leaves', tree.leavesMesh]]) {
  const g = mesh.geometry;
  meshes[name] = {
    position: Array.from(g.attributes.position.array),
    normal: Array.from(g.attributes.normal.array),
    uv: Array.from(g.attributes.uv.array),
    index: Array.from(g.index.array),
  };
}
fs.writeFileSync(out, JSON.stringify({ preset, options: tree.options, meshes }));
const tris = (m) => m.index.length / 3;
console.log(`${preset}: ${tris(meshes.bark)} bark and ${tris(meshes.leaves)} leaf triangles`);
