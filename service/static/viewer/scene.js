// The 3-D scene: organs from the phantom's .glb, site markers, ray paths. Phantom frame: metres, z up.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { errorEllipsoid } from './ellipsoid.js';
import { gainColour, tissueColour } from './palette.js';

export const BACKGROUND = 0x14171c;
const CAPSULE = 0xff8c1a;
const SENSOR = 0x3d8bfd;
const IDLE = 0x5d6677;
const ESTIMATE = 0x39e07a; // a localization's estimate and its error ellipsoid
const ELLIPSOID_OPACITY = 0.45;
const PATHS_UNDER_FIX = 0.2; // the paths' opacity while a fix is shown, so that it stands out
const SHELL_OPACITY = 0.08; // organs that hold other organs (skin, fat, muscle wall...)
const ORGAN_OPACITY = 0.4;

export class Scene3D {
  constructor(container) {
    this.container = container;
    // preserveDrawingBuffer: the canvas can be read back (screenshots, the browser tests)
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.renderer.setClearColor(BACKGROUND);
    container.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.001, 100);
    this.camera.up.set(0, 0, 1);
    this.scene.add(new THREE.AmbientLight(0xffffff, 1.2));
    const light = new THREE.DirectionalLight(0xffffff, 1.6);
    light.position.set(0.3, -1, 0.6);
    this.camera.add(light);
    this.scene.add(this.camera);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.render());
    this.organs = new THREE.Group();
    this.sites = new THREE.Group();
    this.paths = new THREE.Group();
    this.fix = new THREE.Group(); // a localization: estimate, error ellipsoid, true position, error vector
    this.coverage = new THREE.Group(); // a design coverage: the skin's candidates coloured by a metric
    this.scene.add(this.organs, this.sites, this.paths, this.fix, this.coverage);
    this.frames = 0;
    this.pathOpacity = 1.0;
    this.focused = null; // the receiver whose paths are in front
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.container;
    if (!w || !h) return;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
    this.frames += 1;
  }

  /** Replace the organs by those of a .glb; returns {organ name: [meshes]}. `organs` is the phantom's
   *  organ list (name, tissue, parent): the colour is the tissue's, shells are fainter than leaves. */
  async loadOrgans(glb, organs, scale) {
    clear(this.organs);
    const gltf = await new GLTFLoader().parseAsync(glb, '');
    const byName = Object.fromEntries(organs.map((o) => [o.name, o]));
    const parents = new Set(organs.map((o) => o.parent));
    const meshes = {};
    gltf.scene.scale.setScalar(scale);
    gltf.scene.traverse((obj) => {
      if (!obj.isMesh) return;
      const name = nodeName(gltf, obj);
      const organ = byName[name] || { name, tissue: null };
      const shell = parents.has(name);
      obj.geometry.computeVertexNormals();
      obj.material = new THREE.MeshLambertMaterial({
        color: new THREE.Color(tissueColour(organ.tissue, name)), transparent: true,
        opacity: shell ? SHELL_OPACITY : ORGAN_OPACITY, depthWrite: false, side: THREE.DoubleSide,
      });
      obj.renderOrder = shell ? 0 : 1;
      (meshes[name] ||= []).push(obj);
    });
    this.organs.add(gltf.scene);
    return meshes;
  }

  /** Markers of the sites {name: {kind, position_m}}; `size_m` their radius. */
  setSites(sites, size_m) {
    clear(this.sites);
    const sphere = new THREE.SphereGeometry(size_m, 16, 12);
    const box = new THREE.BoxGeometry(1.4 * size_m, 1.4 * size_m, 1.4 * size_m);
    for (const [name, site] of Object.entries(sites)) {
      const capsule = site.kind === 'capsule';
      const marker = new THREE.Mesh(capsule ? sphere : box, new THREE.MeshBasicMaterial({ color: IDLE }));
      marker.position.fromArray(site.position_m);
      marker.userData = { name, kind: site.kind };
      marker.renderOrder = 3;
      this.sites.add(marker);
    }
  }

  /** Colour the markers: the picked capsule orange, the picked sensors blue, the rest grey. */
  markSites(capsule, sensors) {
    for (const marker of this.sites.children) {
      const { name, kind } = marker.userData;
      const on = kind === 'capsule' ? name === capsule : sensors.has(name);
      marker.material.color.setHex(on ? (kind === 'capsule' ? CAPSULE : SENSOR) : IDLE);
      marker.scale.setScalar(on ? 1.0 : 0.7);
    }
    this.render();
  }

  /** The site marker under a pointer event, or null. */
  pick(event) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
      -((event.clientY - rect.top) / rect.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const hit = ray.intersectObjects(this.sites.children, false)[0];
    return hit ? hit.object.userData : null;
  }

  /** Look at a box [[xmin, ymin, zmin], [xmax, ymax, zmax]] from the front (-y), a little above. */
  fit(bounds) {
    const box = new THREE.Box3(new THREE.Vector3(...bounds[0]), new THREE.Vector3(...bounds[1]));
    const centre = box.getCenter(new THREE.Vector3());
    const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-3);
    const distance = radius / Math.sin((this.camera.fov * Math.PI) / 360);
    this.camera.position.copy(centre).add(new THREE.Vector3(0.45, -1, 0.35).normalize().multiplyScalar(distance));
    this.camera.near = distance / 1000;
    this.camera.far = distance * 10;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(centre);
    this.controls.update();
    this.render();
  }

  /** Draw every path of a /v1/channel response as a polyline transmitter -> interactions -> receiver,
   *  coloured by its gain from `lowDb` (darkest) to `highDb` (brightest). One line object per receiver. */
  setPaths(channel, lowDb, highDb) {
    clear(this.paths);
    const tx = channel.transmitter.position_m;
    channel.profiles.forEach((profile, r) => {
      const points = [];
      const colours = [];
      for (const path of profile.paths) {
        const rgb = gainColour((path.gain_db - lowDb) / (highDb - lowDb || 1));
        const vertices = [tx, ...path.interactions.map((i) => i.point_m), profile.position_m];
        for (let k = 0; k + 1 < vertices.length; k++) {
          points.push(...vertices[k], ...vertices[k + 1]);
          colours.push(...rgb, ...rgb);
        }
      }
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.Float32BufferAttribute(points, 3));
      geometry.setAttribute('color', new THREE.Float32BufferAttribute(colours, 3));
      const lines = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ vertexColors: true, transparent: true }));
      lines.userData = { receiver: profile.receiver, index: r, paths: profile.paths.length };
      lines.renderOrder = 2;
      this.paths.add(lines);
    });
    this.render();
  }

  clearPaths() {
    clear(this.paths);
    this.render();
  }

  /** Fade every receiver's paths but the selected one's; outline one path of it in white (or none). */
  focus(receiver, path) {
    this.focused = receiver;
    this.fadePaths();
    this.paths.children.filter((l) => l.userData.highlight).forEach((l) => { this.paths.remove(l); l.geometry.dispose(); });
    if (path) {
      const geometry = new THREE.BufferGeometry().setFromPoints(path.map((p) => new THREE.Vector3(...p)));
      const line = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: 0xffffff, depthTest: false }));
      line.userData = { highlight: true };
      line.renderOrder = 4;
      this.paths.add(line);
    }
    this.render();
  }

  /** Draw a position fix: a marker (an octahedron of radius `size_m`) at `estimate_m`, the error ellipsoid
   *  x^T C^-1 x = scale^2 of its covariance C [m^2] around it (a unit sphere scaled by the semi-axes and turned
   *  onto the eigenvectors, semi-transparent, drawn over everything so that an ellipsoid smaller than the marker
   *  still shows), a ring at the true position `truth_m` and the error vector between them. */
  setFix(estimate_m, covariance_m2, scale, truth_m, size_m) {
    clear(this.fix);
    const { axes_m, directions } = errorEllipsoid(covariance_m2, scale);
    const ellipsoid = new THREE.Mesh(new THREE.SphereGeometry(1, 48, 24), new THREE.MeshLambertMaterial({
      color: ESTIMATE, transparent: true, opacity: ELLIPSOID_OPACITY, depthWrite: false, depthTest: false,
    }));
    ellipsoid.position.fromArray(estimate_m);
    const [u, v, w] = directions.map((d) => new THREE.Vector3(...d));
    ellipsoid.quaternion.setFromRotationMatrix(new THREE.Matrix4().makeBasis(u, v, w));
    ellipsoid.scale.fromArray(axes_m.map((a) => Math.max(a, 1e-9))); // a zero scale makes the matrix singular
    ellipsoid.userData = { role: 'ellipsoid' };
    ellipsoid.renderOrder = 6;
    // its principal axes: unit segments in the sphere's frame, so the ellipsoid's scale makes them the semi-axes
    const axes = new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(
      [[1, 0, 0], [0, 1, 0], [0, 0, 1]].flatMap((e) => [new THREE.Vector3(...e).negate(), new THREE.Vector3(...e)])),
    new THREE.LineBasicMaterial({ color: ESTIMATE, depthTest: false }));
    axes.renderOrder = 6;
    ellipsoid.add(axes);
    const marker = new THREE.Mesh(new THREE.OctahedronGeometry(size_m),
      new THREE.MeshBasicMaterial({ color: ESTIMATE, depthTest: false }));
    marker.position.fromArray(estimate_m);
    marker.userData = { role: 'estimate' };
    marker.renderOrder = 5;
    const truth = new THREE.Mesh(new THREE.SphereGeometry(1.6 * size_m, 16, 12),
      new THREE.MeshBasicMaterial({ color: CAPSULE, wireframe: true, depthTest: false }));
    truth.position.fromArray(truth_m);
    truth.userData = { role: 'truth' };
    truth.renderOrder = 5;
    const vector = new THREE.Line(new THREE.BufferGeometry().setFromPoints([truth.position, marker.position]),
      new THREE.LineBasicMaterial({ color: 0xffffff, depthTest: false }));
    vector.userData = { role: 'error' };
    vector.renderOrder = 6;
    this.fix.add(ellipsoid, marker, truth, vector);
    this.pathOpacity = PATHS_UNDER_FIX;
    this.fadePaths();
    this.render();
    return axes_m;
  }

  /** The coverage layer: a disc of radius `size_m` at every candidate [m], coloured on the gain ramp by its
   *  value between `lo` and `hi`; candidates without a value (null: no path) grey and smaller. */
  setCoverage(points_m, values, lo, hi, size_m) {
    clear(this.coverage);
    const geometry = new THREE.SphereGeometry(size_m, 8, 6);
    const material = new THREE.MeshBasicMaterial({ color: 0xffffff });
    const mesh = new THREE.InstancedMesh(geometry, material, points_m.length);
    const m = new THREE.Matrix4();
    const colour = new THREE.Color();
    points_m.forEach((p, i) => {
      const v = values[i];
      m.makeScale(v === null ? 0.5 : 1, v === null ? 0.5 : 1, v === null ? 0.5 : 1).setPosition(p[0], p[1], p[2]);
      mesh.setMatrixAt(i, m);
      if (v === null) colour.setHex(IDLE);
      else colour.setRGB(...gainColour(hi > lo ? (v - lo) / (hi - lo) : 1));
      mesh.setColorAt(i, colour);
    });
    mesh.renderOrder = 2;
    this.coverage.add(mesh);
    this.render();
    return mesh.count;
  }

  clearCoverage() {
    clear(this.coverage);
    this.render();
  }

  clearFix() {
    clear(this.fix);
    this.pathOpacity = 1.0;
    this.fadePaths();
    this.render();
  }

  /** What the drawn fix's objects hold, read back from three.js (for the browser tests): the marker's and the
   *  ellipsoid's world positions [m], the ellipsoid's world matrix (column-major 4x4: its upper 3x3 block A
   *  maps the unit sphere onto the ellipsoid, so A A^T = scale^2 C) and its scale (the semi-axes) [m]. */
  fixReadback() {
    const role = (r) => this.fix.children.find((o) => o.userData.role === r);
    const ellipsoid = role('ellipsoid');
    if (!ellipsoid) return null;
    this.fix.updateMatrixWorld(true);
    return {
      marker_m: role('estimate').getWorldPosition(new THREE.Vector3()).toArray(),
      truth_m: role('truth').getWorldPosition(new THREE.Vector3()).toArray(),
      ellipsoid_centre_m: ellipsoid.getWorldPosition(new THREE.Vector3()).toArray(),
      ellipsoid_matrix: [...ellipsoid.matrixWorld.elements],
      ellipsoid_scale_m: ellipsoid.scale.toArray(),
      ellipsoid_visible: ellipsoid.visible && ellipsoid.material.opacity > 0,
      objects: this.fix.children.length,
    };
  }

  /** The paths' opacities: the focused receiver's (all when none) full, the others faint, all fainter under a fix. */
  fadePaths() {
    for (const lines of this.paths.children) {
      if (lines.userData.highlight) continue;
      const front = this.focused === null || lines.userData.receiver === this.focused;
      lines.material.opacity = this.pathOpacity * (front ? 1.0 : 0.25);
    }
  }

  /** Polylines drawn (one per path), over all receivers. */
  pathCount() {
    return this.paths.children.reduce((n, l) => n + (l.userData.paths || 0), 0);
  }
}

function clear(group) {
  for (const child of [...group.children]) {
    group.remove(child);
    child.traverse((o) => { o.geometry?.dispose(); o.material?.dispose?.(); });
  }
}

/** The glTF node name an object comes from (GLTFLoader sanitises object names; the json keeps them). */
function nodeName(gltf, obj) {
  for (let o = obj; o; o = o.parent) {
    const index = gltf.parser.associations.get(o)?.nodes;
    if (index !== undefined && gltf.parser.json.nodes[index].mesh !== undefined) return gltf.parser.json.nodes[index].name;
  }
  return obj.name;
}
