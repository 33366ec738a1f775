// three.js viewer of a GLB (one tree from POST /v1/trees, or a glb forest job's scene.glb):
// the skinned trees with their wind animation playing, an orbit camera framing the scene.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

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
    this.renderer.render(this.scene, this.camera);
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
    this.root.dataset.state = "ready";
    this.root.dataset.clips = gltf.animations.map((a) => a.name).join(",");
    return { clips: gltf.animations.map((a) => a.name), meshes };
  }
}
