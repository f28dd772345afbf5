// The 3D hand: deploy/hand/hand24.urdf (served as hand24.urdf) parsed into a three.js tree of
// links and revolute joints, posed by HandState's joint angles (URDF document order), with
// the student's thimble spheres and contact forces as arrows, in the device frame.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';

const vec = (s, d = [0, 0, 0]) => (s ? s.trim().split(/\s+/).map(Number) : d);

function originOf(el) {
  const o = el && el.querySelector(':scope > origin');
  const m = new THREE.Matrix4();
  if (!o) return m;
  const [x, y, z] = vec(o.getAttribute('xyz'));
  const [r, p, yw] = vec(o.getAttribute('rpy'));
  m.compose(new THREE.Vector3(x, y, z),
            new THREE.Quaternion().setFromEuler(new THREE.Euler(r, p, yw, 'ZYX')),
            new THREE.Vector3(1, 1, 1));
  return m;
}

export class Hand {
  constructor(container) {
    this.container = container;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xe9edf2);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.005, 5);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(0.05, -0.30, 0.22);
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    container.appendChild(this.renderer.domElement);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8899aa, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.5);
    sun.position.set(0.3, -0.4, 0.8);
    this.scene.add(sun);
    this.root = new THREE.Group();       // the hand's carpus, placed in the device frame
    this.device = new THREE.Group();     // the device frame
    this.device.add(this.root);
    this.scene.add(this.device);
    this.device.add(new THREE.AxesHelper(0.03));
    this.joints = [];                    // URDF order: {name, axis, object, angle}
    this.byName = new Map();
    this.spheres = [0, 1].map((k) => {
      const m = new THREE.Mesh(new THREE.SphereGeometry(0.009, 24, 16),
        new THREE.MeshStandardMaterial({ color: k ? 0x3c78d8 : 0xe69138, transparent: true, opacity: 0.55 }));
      m.visible = false;
      this.device.add(m);
      return m;
    });
    this.arrows = [0, 1].map((k) => {
      const a = new THREE.ArrowHelper(new THREE.Vector3(0, 0, 1), new THREE.Vector3(), 0.01,
                                      k ? 0x1f4fa0 : 0xb45f06, 0.008, 0.005);
      a.visible = false;
      this.device.add(a);
      return a;
    });
    this.resize();
    new ResizeObserver(() => this.resize()).observe(container);
    this.dirty = true;
    // At most about 30 renders a second, and fewer where rendering is slow (a software
    // renderer): the 3D view never takes more than about a quarter of the page's time.
    let last = 0;
    let cost = 0;  // ms per render, smoothed
    const loop = (now) => {
      if (this.dirty && now - last >= Math.max(30, 4 * cost)) {
        last = now;
        this.controls.update();
        this.renderer.render(this.scene, this.camera);
        this.dirty = false;
        cost = 0.8 * cost + 0.2 * (performance.now() - now);
        this.renderMs = cost;
      }
      requestAnimationFrame(loop);
    };
    this.controls.addEventListener('change', () => { this.dirty = true; });
    requestAnimationFrame(loop);
  }

  resize() {
    const w = this.container.clientWidth || 400;
    const h = this.container.clientHeight || 300;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.dirty = true;
  }

  async load(url) {
    const text = await (await fetch(url)).text();
    const doc = new DOMParser().parseFromString(text, 'application/xml');
    const links = new Map();
    const bone = new THREE.MeshStandardMaterial({ color: 0xf1c9a5, roughness: 0.6 });
    for (const l of doc.querySelectorAll('robot > link')) {
      const g = new THREE.Group();
      g.name = l.getAttribute('name');
      for (const c of l.querySelectorAll(':scope > collision, :scope > visual')) {
        const cyl = c.querySelector('geometry > cylinder');
        const sph = c.querySelector('geometry > sphere');
        let geo = null;
        if (cyl) {
          geo = new THREE.CylinderGeometry(+cyl.getAttribute('radius'), +cyl.getAttribute('radius'),
                                           +cyl.getAttribute('length'), 16);
          geo.rotateX(Math.PI / 2);  // three's cylinders lie along y, URDF's along z
        } else if (sph) {
          geo = new THREE.SphereGeometry(+sph.getAttribute('radius'), 16, 12);
        }
        if (!geo) continue;
        const mesh = new THREE.Mesh(geo, bone);
        originOf(c).decompose(mesh.position, mesh.quaternion, mesh.scale);
        g.add(mesh);
        break;  // one shape per link
      }
      links.set(g.name, g);
    }
    const children = new Set();
    for (const j of doc.querySelectorAll('robot > joint')) {
      const parent = links.get(j.querySelector('parent').getAttribute('link'));
      const child = links.get(j.querySelector('child').getAttribute('link'));
      const frame = new THREE.Group();  // the joint's origin in its parent
      originOf(j).decompose(frame.position, frame.quaternion, frame.scale);
      const moving = new THREE.Group();  // rotates about the axis
      frame.add(moving);
      moving.add(child);
      parent.add(frame);
      children.add(child.name);
      const axis = new THREE.Vector3(...vec(j.querySelector('axis')?.getAttribute('xyz'), [1, 0, 0]))
        .normalize();
      const joint = { name: j.getAttribute('name'), axis, object: moving, angle: 0 };
      this.joints.push(joint);
      this.byName.set(joint.name, joint);
    }
    for (const [name, g] of links) if (!children.has(name)) this.root.add(g);
    this.dirty = true;
  }

  /// Every joint at rest (a replay where its hand was not computed poses the index MCP only).
  rest() {
    for (const j of this.joints) this.setJoint(j.name, 0);
    for (const k of [0, 1]) { this.spheres[k].visible = false; this.arrows[k].visible = false; }
  }

  /// HandState.joint_angles_rad's order: the joint names, as the gateway's hello tells them.
  setDofs(names) { this.dofs = names; }

  setJoint(name, angle) {
    const j = this.byName.get(name);
    if (!j || !Number.isFinite(angle)) return;
    j.angle = angle;
    j.object.quaternion.setFromAxisAngle(j.axis, angle);
    this.dirty = true;
  }

  /// A HandState frame, live or a replay's (or a replay sample: mcp only).
  pose(f) {
    if (Array.isArray(f.joints) && f.joints.length && this.dofs) {
      f.joints.forEach((a, i) => this.setJoint(this.dofs[i], a));
    } else if (f.mcp) {
      this.setJoint('index_mcp_flexion', f.mcp[0]);
      this.setJoint('index_mcp_abduction', f.mcp[1]);
      this.setJoint('index_mcp_axial', f.mcp[2]);
    }
    if (f.bone0) {
      const [x, y, z, qw, qx, qy, qz] = f.bone0;
      this.root.position.set(x, y, z);
      this.root.quaternion.set(qx, qy, qz, qw);
    }
    for (let k = 0; k < 2; ++k) {
      const s = f.sphere && f.sphere[k];
      this.spheres[k].visible = !!s;
      if (s) this.spheres[k].position.set(...s);
      const c = f.contact && f.contact[k];
      const mag = c ? Math.hypot(...c) : 0;
      this.arrows[k].visible = !!s && mag > 0.05;
      if (s && mag > 0.05) {
        this.arrows[k].position.set(...s);
        this.arrows[k].setDirection(new THREE.Vector3(...c).divideScalar(mag));
        this.arrows[k].setLength(Math.min(0.004 * mag + 0.01, 0.12), 0.008, 0.005);
      }
    }
    if (!this.framed && f.bone0) {  // look at the hand once it is placed
      this.framed = true;
      this.controls.target.set(f.bone0[0] + 0.07, f.bone0[1], f.bone0[2]);
      this.camera.position.set(f.bone0[0] + 0.02, f.bone0[1] - 0.17, f.bone0[2] + 0.12);
    }
    this.dirty = true;
  }

  /// The index MCP flexion as the 3D model holds it now, radians.
  mcpFlexion() { return this.byName.get('index_mcp_flexion')?.angle; }
}
