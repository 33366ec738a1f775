// three.js viewer of a GLB (one tree from POST /v1/trees, or a glb forest job's scene.glb):
// the skinned trees with their wind animation playing, an orbit camera framing the scene, and
// each tree's levels of detail (MSFT_lod) switched by its size on screen.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { MeshoptDecoder } from "three/addons/libs/meshopt_decoder.module.js";

/**
 * Each node with MSFT_lod becomes a THREE.LOD: its own object at level 0, then the nodes its
 * `ids` name (not in the scene: GLTFLoader leaves them out), each from the distance where the
 * tree's height covers the fraction of the view that the node's MSFT_screencoverage extras
 * give for the level before it. The LOD nodes share the tree's skin, so the wind moves them.
 */
async function levelsOfDetail(gltf, fovDeg) {
  const lods = [];
  const holders = [];
  gltf.scene.traverse((o) => {
    if (o.userData?.gltfExtensions?.MSFT_lod) holders.push(o);
  });
  const tan = Math.tan(THREE.MathUtils.degToRad(fovDeg / 2));
  for (const node of holders) {
    const ids = node.userData.gltfExtensions.MSFT_lod.ids ?? [];
    const coverage = node.userData.MSFT_screencoverage ?? [];
    const others = await Promise.all(ids.map((i) => gltf.parser.getDependency("node", i)));
    const box = new THREE.Box3().setFromObject(node);
    const height = Math.max(box.getSize(new THREE.Vector3()).y, 0.1);
    const lod = new THREE.LOD();
    lod.name = `${node.name}_levels`;
    // skinned meshes stand at the scene's origin (their joints place them): measure the
    // camera's distance from the tree itself, not from the LOD object
    lod.userData.centre = box.getCenter(new THREE.Vector3());
    lod.autoUpdate = false;
    node.parent.add(lod);
    lod.addLevel(node, 0);
    others.forEach((other, k) => {
      const c = Math.max(coverage[k] ?? 0.5 / 2 ** k, 1e-4);
      lod.addLevel(other, height / (c * 2 * tan));
    });
    lods.push(lod);
  }
  return lods;
}

const _eye = new THREE.Vector3();

/** THREE.LOD's own level choice, from the tree's centre (see levelsOfDetail). */
function chooseLevel(lod, camera) {
  const levels = lod.levels;
  const distance = _eye.setFromMatrixPosition(camera.matrixWorld).distanceTo(lod.userData.centre) / camera.zoom;
  let i = 1;
  levels[0].object.visible = true;
  for (; i < levels.length; i += 1) {
    let at = levels[i].distance;
    if (levels[i].object.visible) at -= at * levels[i].hysteresis;
    if (distance < at) break;
    levels[i - 1].object.visible = false;
    levels[i].object.visible = true;
  }
  lod._currentLevel = i - 1;
  for (; i < levels.length; i += 1) levels[i].object.visible = false;
}

export const BACKGROUND = 0xdfe8ee;

export class Viewer {
  constructor(canvas, root) {
    this.root = root;
    // preserveDrawingBuffer: the tests (and a user's screenshot) read the canvas back
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.renderer.outputColorSpace = THREE.SRGBColorSpace;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    this.scene.add(new THREE.HemisphereLight(0xeef4ff, 0x4a3f2c, 1.6));
    const sun = new THREE.DirectionalLight(0xfff4e0, 2.2);
    sun.position.set(5, 10, 4);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.05, 5000);
    this.camera.position.set(6, 4, 6);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = true;
    this.clock = new THREE.Clock();
    this.mixer = null;
    this.model = null;
    this.loader = new GLTFLoader();
    this.loader.setMeshoptDecoder(MeshoptDecoder); // a --glb-pack meshopt file
    this.lods = [];
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    this.renderer.setAnimationLoop(() => this.frame());
  }

  resize() {
    const c = this.renderer.domElement;
    const w = c.clientWidth || 1;
    const h = c.clientHeight || 1;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  frame() {
    const dt = this.clock.getDelta();
    if (this.mixer) this.mixer.update(dt);
    this.controls.update();
    this.camera.updateMatrixWorld();
    for (const lod of this.lods) chooseLevel(lod, this.camera);
    this.renderer.render(this.scene, this.camera);
    if (this.lods.length) {
      // the first tree's level, for the tests
      const level = String(this.lods[0].getCurrentLevel());
      if (this.root.dataset.lod !== level) this.root.dataset.lod = level;
    }
  }

  /** Move the camera along its view to ``factor`` times its distance from the target. */
  zoom(factor) {
    const offset = this.camera.position.clone().sub(this.controls.target).multiplyScalar(factor);
    this.camera.position.copy(this.controls.target).add(offset);
    this.camera.far = Math.max(this.camera.far, offset.length() * 4);
    this.camera.updateProjectionMatrix();
  }

  /** Show a .glb (ArrayBuffer); resolves with {clips, meshes} once it is in the scene. */
  async show(buffer) {
    const gltf = await this.loader.parseAsync(buffer, "");
    if (this.model) {
      this.scene.remove(this.model);
      this.model.traverse((o) => {
        o.geometry?.dispose?.();
      });
    }
    this.model = gltf.scene;
    this.model.traverse((o) => {
      // leaf cards are cut by alpha (MASK, cutoff 0.5); small leaves seen from afar read
      // from mip levels whose averaged alpha falls under the cutoff and vanish: test lower,
      // and let MSAA smooth the cut edges instead
      for (const m of [o.material].flat()) {
        if (m && m.alphaTest > 0) {
          m.alphaTest = 0.2;
          m.alphaToCoverage = true;
        }
      }
    });
    this.lods = await levelsOfDetail(gltf, this.camera.fov);
    this.scene.add(this.model);
    this.mixer = null;
    if (gltf.animations.length) {
      this.mixer = new THREE.AnimationMixer(this.model);
      for (const clip of gltf.animations) this.mixer.clipAction(clip).play();
    }
    // frame the whole model: orbit about its box's centre, back off until its largest extent
    // fills the view (a bounding sphere leaves a tall, narrow tree small)
    const box = new THREE.Box3().setFromObject(this.model);
    const size = box.getSize(new THREE.Vector3());
    const center = box.getCenter(new THREE.Vector3());
    const extent = Math.max(size.x, size.y, size.z, 0.1);
    const dist = (0.6 * extent) / Math.tan(THREE.MathUtils.degToRad(this.camera.fov / 2)) + Math.max(size.x, size.z) / 2;
    this.controls.target.copy(center);
    const dir = new THREE.Vector3(1, 0.25, 1).normalize();
    this.camera.position.copy(center).addScaledVector(dir, dist);
    this.camera.near = dist / 100;
    this.camera.far = dist * 10;
    this.camera.updateProjectionMatrix();
    let meshes = 0;
    this.model.traverse((o) => {
      if (o.isMesh) meshes += 1;
    });
    const levels = this.lods.length ? this.lods[0].levels.length : 1;
    this.root.dataset.levels = String(levels);
    this.root.dataset.state = "ready";
    this.root.dataset.clips = gltf.animations.map((a) => a.name).join(",");
    return { clips: gltf.animations.map((a) => a.name), meshes, levels };
  }
}
