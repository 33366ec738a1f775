// Load a .glb with three.js's GLTFLoader (with its MeshoptDecoder, for EXT_meshopt_compression)
// under Node and report what it made; with --times,
// also the world-space skinned vertex positions of every SkinnedMesh at those seconds of the
// first animation (float32, mesh after mesh, time after time) written to --out. With --lods,
// also every lower level of detail a node names with MSFT_lod (nodes in no scene, which
// GLTFLoader leaves out: loaded through its parser), reported under "lods" and, with --times,
// their SkinnedMesh vertices after the scene's, level after level.
//   node three_load.mjs FILE.glb [--times 0,0.125 --out POS.bin] [--lods]
import { readFileSync, writeFileSync } from 'node:fs';

// the few browser globals GLTFLoader touches: images arrive as Blobs, which we do not decode
// (a stand-in bitmap of the PNG header's size), so no canvas or DOM is needed
globalThis.self = globalThis;
const images = [];
globalThis.createImageBitmap = async (blob) => {
  const bytes = new Uint8Array(await blob.arrayBuffer());
  const view = new DataView(bytes.buffer);
  const png = bytes[1] === 0x50 && bytes[2] === 0x4e && bytes[3] === 0x47;
  const bitmap = { width: png ? view.getUint32(16) : 0, height: png ? view.getUint32(20) : 0, close() {} };
  images.push({ type: blob.type, bytes: bytes.length, ...bitmap });
  return bitmap;
};
const realFetch = globalThis.fetch;
globalThis.fetch = async (url, opts) => {
  if (String(url).startsWith('blob:')) {
    const { resolveObjectURL } = await import('node:buffer');
    const blob = resolveObjectURL(String(url));
    return new Response(blob);
  }
  return realFetch(url, opts);
};

const THREE = await import('three');
const { GLTFLoader } = await import('three/examples/jsm/loaders/GLTFLoader.js');
const { MeshoptDecoder } = await import('three/examples/jsm/libs/meshopt_decoder.module.js');

const args = process.argv.slice(2);
const file = args[0];
const opt = (name) => { const i = args.indexOf(name); return i < 0 ? null : args[i + 1]; };
const data = readFileSync(file);
const buffer = data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);

const gltf = await new Promise((resolve, reject) =>
  new GLTFLoader().setMeshoptDecoder(MeshoptDecoder).parse(buffer, '', resolve, (e) => reject(e)));
// let texture promises settle (images decode asynchronously)
await new Promise((r) => setTimeout(r, 50));

const skinned = [];
const textured = new Set();
let cards = 0;
gltf.scene.traverse((o) => {
  if (o.isSkinnedMesh) skinned.push(o);
  if (o.isMesh) {
    const m = o.material;
    if (m.map) textured.add(m.map.uuid);
    if (m.alphaTest > 0 && m.side === THREE.DoubleSide) cards += 1;
  }
});
const report = {
  scenes: gltf.scenes.map((s) => s.name),
  skinned_meshes: skinned.map((m) => ({
    name: m.name,
    vertices: m.geometry.attributes.position.count,
    bones: m.skeleton.bones.length,
    has_texture: !!m.material.map,
  })),
  animations: gltf.animations.map((a) => ({ name: a.name, duration: a.duration, tracks: a.tracks.length })),
  textures: textured.size,
  images,
  leaf_card_meshes: cards,
};

if (args.includes('--lods')) {
  const parser = gltf.parser;
  report.lods = [];
  for (const [index, def] of (parser.json.nodes || []).entries()) {
    const ids = def.extensions?.MSFT_lod?.ids;
    if (!ids) continue;
    const top = await parser.getDependency('node', index);
    const topBones = new Set();
    top.traverse((o) => { if (o.isSkinnedMesh) o.skeleton.bones.forEach((b) => topBones.add(b)); });
    for (const id of ids) {
      const node = await parser.getDependency('node', id);
      const meshes = [];
      node.traverse((o) => { if (o.isSkinnedMesh) meshes.push(o); });
      report.lods.push({
        of: def.name,
        name: parser.json.nodes[id].name,
        in_scene: node.parent !== null,
        skinned_meshes: meshes.map((m) => ({
          name: m.name,
          vertices: m.geometry.attributes.position.count,
          bones: m.skeleton.bones.length,
          shares_bones: m.skeleton.bones.every((b) => topBones.has(b)),
          has_texture: !!m.material.map,
          alpha_test: m.material.alphaTest,
        })),
      });
      skinned.push(...meshes);
    }
  }
}

const times = opt('--times');
if (times) {
  const mixer = new THREE.AnimationMixer(gltf.scene);
  if (gltf.animations.length) mixer.clipAction(gltf.animations[0]).play();
  const out = [];
  const v = new THREE.Vector3();
  for (const t of times.split(',').map(Number)) {
    mixer.setTime(t);
    gltf.scene.updateMatrixWorld(true);
    for (const mesh of skinned) {
      mesh.skeleton.update();
      const pos = mesh.geometry.attributes.position;
      const arr = new Float32Array(pos.count * 3);
      for (let i = 0; i < pos.count; i++) {
        v.fromBufferAttribute(pos, i);
        mesh.applyBoneTransform(i, v);
        v.applyMatrix4(mesh.matrixWorld);
        arr[3 * i] = v.x; arr[3 * i + 1] = v.y; arr[3 * i + 2] = v.z;
      }
      out.push(Buffer.from(arr.buffer));
    }
  }
  writeFileSync(opt('--out'), Buffer.concat(out));
}
process.stdout.write(JSON.stringify(report));
