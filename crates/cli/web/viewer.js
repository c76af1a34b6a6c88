// The material on its flat patch in three.js (which implements
// KHR_materials_anisotropy), lit by one directional light.
//
// show(url, el) frames the patch for the operator (drag to turn). With
// `view` it sets up the scene `refl render --model ggx_aniso --light
// directional:ELEV,AZ --camera POLAR,AZ` draws: the camera 400 mm from the
// sample's centre with an 18 degree vertical field of view, a distant
// light of irradiance `view.intensity` (refl's is 1), nothing else, so the
// two images compare pixel for pixel. Angles are in the sample's frame (z its normal); glTF is
// y-up, sample (x, y, z) being glTF (x, z, -y) (`assess::gltf`).
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

let current = null;
const rad = (d) => (d * Math.PI) / 180;
// A sample-frame direction as glTF's.
const gltfDir = (x, y, z) => new THREE.Vector3(x, z, -y);

export async function show(url, el, view) {
  if (current) { current.dispose(); current = null; }
  const renderer = new THREE.WebGLRenderer({ antialias: !view, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(el.clientWidth, el.clientHeight);
  el.innerHTML = "";
  el.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x000000);
  const camera = new THREE.PerspectiveCamera(view ? 18 : 35, el.clientWidth / el.clientHeight, 0.001, 100);
  const light = new THREE.DirectionalLight(0xffffff, view ? (view.intensity ?? 1.0) : 3.0);
  scene.add(light);
  const gltf = await new GLTFLoader().loadAsync(url);
  scene.add(gltf.scene);
  const centre = new THREE.Vector3();
  if (view) {
    const [polar, az] = view.camera.map(rad);
    camera.position.copy(gltfDir(Math.sin(polar) * Math.cos(az), Math.sin(polar) * Math.sin(az), Math.cos(polar)).multiplyScalar(0.4));
    const [elev, laz] = view.light.map(rad);
    light.position.copy(gltfDir(Math.cos(elev) * Math.cos(laz), Math.cos(elev) * Math.sin(laz), Math.sin(elev)));
  } else {
    scene.add(new THREE.AmbientLight(0xffffff, 0.05));
    // From above at 45 degrees, the light opposite.
    const box = new THREE.Box3().setFromObject(gltf.scene);
    const size = box.getSize(new THREE.Vector3()).length();
    box.getCenter(centre);
    camera.position.copy(centre).add(new THREE.Vector3(0, size * 0.9, size * 0.9));
    light.position.copy(centre).add(new THREE.Vector3(0, size, -size));
  }
  light.target.position.copy(centre);
  scene.add(light.target);
  camera.lookAt(centre);
  let running = true;
  if (view) {
    renderer.render(scene, camera);
  } else {
    const controls = new OrbitControls(camera, renderer.domElement);
    controls.target.copy(centre);
    controls.update();
    const draw = () => {
      if (!running) return;
      renderer.render(scene, camera);
      requestAnimationFrame(draw);
    };
    draw();
  }
  current = { dispose: () => { running = false; renderer.dispose(); } };
  window.reflectometerViewer = { drawn: true, nodes: gltf.scene.children.length };
}
