// The browser view of `depthmesh serve`: `/` lists the sessions, `/view/NAME`
// shows one growing. The token is asked for once (or taken from a
// `#token=T` fragment, which never reaches the server) and kept for the tab.
//
// A session's map arrives as keyed parts (TSDF blocks, groups of plane
// windows, MABDI patches), each compressed with meshoptimizer's codecs; a
// newer version of a part replaces the older, an empty one deletes it. Parts
// are drawn in groups (their keys shifted right by `group_bits`), so a room
// is a few hundred draw calls however finely it is cut.

import {
  AmbientLight, BufferAttribute, BufferGeometry, DirectionalLight, DoubleSide,
  Group, Line, LineBasicMaterial, LineSegments, Matrix4, Mesh,
  MeshLambertMaterial, MeshoptDecoder, OrbitControls, PerspectiveCamera,
  Points, PointsMaterial, Scene, Vector3, WebGLRenderer,
} from './vendor.min.js';

const TOKEN_KEY = 'depthmesh-token';
const $ = (id) => document.getElementById(id);

/** The token: from the address's fragment (then kept), or kept earlier. */
function currentToken() {
  const m = location.hash.match(/token=([^&]*)/);
  if (m) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(m[1]));
    history.replaceState(null, '', location.pathname + location.search);
  }
  return sessionStorage.getItem(TOKEN_KEY);
}

function showError(message) {
  $('error').textContent = message;
  $('error').hidden = false;
}

function askToken() {
  const form = $('login');
  form.hidden = false;
  $('token').focus();
  form.onsubmit = (e) => {
    e.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $('token').value);
    form.hidden = true;
    $('error').hidden = true;
    main();
  };
}

async function listSessions(token) {
  const r = await fetch('/api/sessions', { headers: { Authorization: `Bearer ${token}` } });
  if (r.status === 401) throw new Error('unauthorised');
  if (!r.ok) throw new Error(`the server answered ${r.status}`);
  return (await r.json()).sessions;
}

async function main() {
  const token = currentToken();
  if (!token) return askToken();
  let sessions;
  try {
    sessions = await listSessions(token);
  } catch (e) {
    if (e.message === 'unauthorised') {
      sessionStorage.removeItem(TOKEN_KEY);
      showError('Wrong token: the server refused it. Enter the token `depthmesh serve` printed.');
      return askToken();
    }
    return showError(`Cannot reach the server: ${e.message}`);
  }
  if (location.pathname.startsWith('/view/')) {
    const name = decodeURIComponent(location.pathname.slice('/view/'.length));
    if (!sessions.some((s) => s.name === name)) return showError(`No session named ${name}.`);
    return new View(name, token).open();
  }
  showList(sessions, token);
}

function showList(sessions, token) {
  $('list').hidden = false;
  const render = (list) => {
    $('none').hidden = list.length > 0;
    $('sessions').replaceChildren(...list.map((s) => {
      const row = document.createElement('tr');
      const link = document.createElement('a');
      link.href = `/view/${encodeURIComponent(s.name)}`;
      link.textContent = s.name;
      const cells = [link, s.map, s.live ? 'live' : 'finished', s.frames, s.triangles ?? '–'];
      for (const c of cells) {
        const td = document.createElement('td');
        td.append(c instanceof Node ? c : String(c));
        row.append(td);
      }
      return row;
    }));
  };
  render(sessions);
  setInterval(() => listSessions(token).then(render).catch(() => {}), 2000);
}

/** Reads a part message (see the server's `view::wire`). */
function readPart(buffer) {
  const view = new DataView(buffer);
  const key = [view.getInt32(4, true), view.getInt32(8, true), view.getInt32(12, true)];
  const flags = view.getUint32(16, true);
  const vertices = view.getUint32(20, true);
  const indices = view.getUint32(24, true);
  if (vertices === 0) return { key, triangles: 0 };
  const origin = [view.getInt32(28, true), view.getInt32(32, true), view.getInt32(36, true)];
  const step = view.getFloat32(40, true);
  const vertexBytes = view.getUint32(44, true);
  const raw = new Uint8Array(vertices * 12);
  MeshoptDecoder.decodeVertexBuffer(raw, vertices, 12, new Uint8Array(buffer, 48, vertexBytes));
  const index = new Uint32Array(indices);
  MeshoptDecoder.decodeIndexBuffer(new Uint8Array(index.buffer), indices, 4,
    new Uint8Array(buffer, 48 + vertexBytes));
  const q = new Uint16Array(raw.buffer);
  // Grid coordinates (quanta): where parts share a vertex, they agree.
  const grid = new Int32Array(vertices * 3);
  const color = flags & 1 ? new Uint8Array(vertices * 3) : null;
  for (let v = 0; v < vertices; v++) {
    for (let c = 0; c < 3; c++) {
      grid[3 * v + c] = origin[c] + q[6 * v + c];
      if (color) color[3 * v + c] = raw[12 * v + 8 + c];
    }
  }
  return { key, step, grid, color, index, triangles: indices / 3 };
}

/** Largest grid span (quanta per axis) a group's vertices are joined over. */
const JOIN_SPAN = 1 << 17;

/** A session's view: the map, the sensor, the figures. */
class View {
  constructor(name, token) {
    this.name = name;
    this.token = token;
    this.parts = new Map(); // part key -> part
    this.groups = new Map(); // group key -> { mesh, keys: Set, dirty }
    this.triangles = 0;
    this.received = 0;
    this.receivedThen = 0;
    this.follow = true;
    this.framed = false;
    this.groupBits = 0;
    this.joinVertices = true;
    this.trail = [];
    this.up = null;
  }

  async open() {
    // For scripts driving the page (tests, benchmarks).
    window.depthmeshView = this;
    $('view').hidden = false;
    $('title').textContent = this.name;
    await MeshoptDecoder.ready;
    this.setupScene();
    this.setupControls();
    const url = new URL(`/ws/view/${encodeURIComponent(this.name)}`, location.href);
    url.protocol = location.protocol === 'https:' ? 'wss:' : 'ws:';
    url.searchParams.set('token', this.token);
    const socket = new WebSocket(url);
    socket.binaryType = 'arraybuffer';
    socket.onmessage = (e) => this.receive(e.data);
    socket.onclose = () => { if (!this.ended) $('state').textContent = 'disconnected'; };
    socket.onerror = () => showError('The view\'s connection failed.');
    setInterval(() => this.everySecond(), 1000);
  }

  setupScene() {
    const host = $('canvas');
    // No multisampling: on a software GL it would cost most of the frame.
    this.renderer = new WebGLRenderer({ antialias: false });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    host.append(this.renderer.domElement);
    this.scene = new Scene();
    this.camera = new PerspectiveCamera(60, 1, 0.02, 200);
    this.camera.position.set(0, -1, -2);
    this.scene.add(new AmbientLight(0xffffff, 0.45));
    this.light = new DirectionalLight(0xffffff, 1.1);
    this.camera.add(this.light);
    this.scene.add(this.camera);
    this.map = new Group();
    this.scene.add(this.map);
    this.shaded = new MeshLambertMaterial({ color: 0xb8bcc4, side: DoubleSide });
    this.coloured = new MeshLambertMaterial({ vertexColors: true, side: DoubleSide });
    this.trailLine = new Line(new BufferGeometry(), new LineBasicMaterial({ color: 0xffd040 }));
    this.lostPoints = new Points(new BufferGeometry(), new PointsMaterial({ color: 0xff3030, size: 6, sizeAttenuation: false }));
    this.frustum = new LineSegments(new BufferGeometry(), new LineBasicMaterial({ color: 0x40ff80 }));
    this.frustum.matrixAutoUpdate = false;
    this.scene.add(this.trailLine, this.lostPoints, this.frustum);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('start', () => this.setFollow(false));
    this.frames = 0;
    const resize = () => {
      const w = host.clientWidth; const h = host.clientHeight;
      this.renderer.setSize(w, h, false);
      this.camera.aspect = w / Math.max(h, 1);
      this.camera.updateProjectionMatrix();
    };
    new ResizeObserver(resize).observe(host);
    resize();
    const loop = () => {
      this.rebuildGroups(8);
      this.controls.update();
      this.renderer.render(this.scene, this.camera);
      this.frames++;
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  setupControls() {
    $('follow').onclick = () => this.setFollow(!this.follow);
    const link = $('download-glb');
    const update = () => {
      const ratio = $('simplify').value;
      const query = new URLSearchParams({ token: this.token });
      if (ratio !== '1') query.set('simplify', ratio);
      link.href = `/api/sessions/${encodeURIComponent(this.name)}/mesh.glb?${query}`;
      link.download = `${this.name}.glb`;
    };
    $('simplify').onchange = update;
    update();
  }

  setFollow(on) {
    this.follow = on;
    $('follow').textContent = on ? 'Free camera' : 'Follow sensor';
  }

  receive(data) {
    if (typeof data === 'string') {
      this.received += data.length;
      const m = JSON.parse(data);
      if (m.type === 'info') this.info(m);
      else if (m.type === 'figures') this.figures(m);
      else if (m.type === 'trail') this.addTrail(m);
      else if (m.type === 'ended') this.end(m);
      return;
    }
    this.received += data.byteLength;
    const magic = String.fromCharCode(...new Uint8Array(data, 0, 4));
    if (magic === 'DMV1') this.applyPart(readPart(data));
    else if (magic === 'DMI1') this.showImage(new DataView(data).getUint32(4, true), data.slice(8));
  }

  info(m) {
    this.groupBits = m.group_bits;
    this.joinVertices = m.join;
    this.intrinsics = m.camera;
    $('state').textContent = `${m.map} · live`;
    const k = m.camera; const z = 0.25;
    const corner = (u, v) => [(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z];
    const c = [corner(0, 0), corner(k.width, 0), corner(k.width, k.height), corner(0, k.height)];
    const lines = [];
    for (let i = 0; i < 4; i++) lines.push(0, 0, 0, ...c[i], ...c[i], ...c[(i + 1) % 4]);
    this.frustum.geometry.setAttribute('position', new BufferAttribute(new Float32Array(lines), 3));
  }

  applyPart(part) {
    const id = part.key.join(',');
    const old = this.parts.get(id);
    if (old) this.triangles -= old.triangles;
    if (part.triangles === 0) this.parts.delete(id);
    else this.parts.set(id, part);
    this.triangles += part.triangles;
    $('triangles').textContent = String(this.triangles);
    $('parts').textContent = String(this.parts.size);
    const b = this.groupBits;
    const gid = part.key.map((k) => k >> b).join(',');
    let group = this.groups.get(gid);
    if (!group) {
      group = { mesh: null, keys: new Set(), dirty: false };
      this.groups.set(gid, group);
    }
    if (part.triangles === 0) group.keys.delete(id); else group.keys.add(id);
    group.dirty = true;
  }

  /** Rebuilds changed groups' meshes, for at most `budget` ms. */
  rebuildGroups(budget) {
    const start = performance.now();
    for (const [gid, group] of this.groups) {
      if (!group.dirty) continue;
      if (performance.now() - start > budget) break;
      group.dirty = false;
      if (group.mesh) {
        this.map.remove(group.mesh);
        group.mesh.geometry.dispose();
        group.mesh = null;
      }
      const parts = [...group.keys].map((k) => this.parts.get(k));
      if (parts.length === 0) { this.groups.delete(gid); continue; }
      group.mesh = this.groupMesh(parts);
      this.map.add(group.mesh);
    }
    if (!this.framed && this.parts.size > 0 && !this.follow) this.frameAll();
  }

  /**
   * One mesh of a group's parts. Vertices the parts share (the same grid
   * point) are joined, so normals computed from the triangles are smooth
   * across the parts' borders.
   */
  groupMesh(parts) {
    let vertices = 0; let indices = 0;
    const low = [Infinity, Infinity, Infinity]; const high = [-Infinity, -Infinity, -Infinity];
    for (const p of parts) {
      vertices += p.grid.length / 3; indices += p.index.length;
      for (let i = 0; i < p.grid.length; i++) {
        low[i % 3] = Math.min(low[i % 3], p.grid[i]);
        high[i % 3] = Math.max(high[i % 3], p.grid[i]);
      }
    }
    const step = parts[0].step;
    const join = this.joinVertices && parts.every((p) => p.step === step)
      && high.every((h, c) => h - low[c] < JOIN_SPAN);
    const withColours = parts.every((p) => p.color);
    const position = new Float32Array(vertices * 3);
    const color = withColours ? new Uint8Array(vertices * 3) : null;
    const index = new Uint32Array(indices);
    const seen = new Map();
    let n = 0; let i = 0;
    for (const p of parts) {
      const count = p.grid.length / 3;
      const local = new Uint32Array(count);
      for (let v = 0; v < count; v++) {
        const x = p.grid[3 * v]; const y = p.grid[3 * v + 1]; const z = p.grid[3 * v + 2];
        let at;
        if (join) {
          const k = ((x - low[0]) * JOIN_SPAN + (y - low[1])) * JOIN_SPAN + (z - low[2]);
          at = seen.get(k);
          if (at === undefined) { at = n++; seen.set(k, at); } else { local[v] = at; continue; }
        } else {
          at = n++;
        }
        local[v] = at;
        position[3 * at] = x * p.step; position[3 * at + 1] = y * p.step; position[3 * at + 2] = z * p.step;
        if (color) color.set(p.color.subarray(3 * v, 3 * v + 3), 3 * at);
      }
      for (let j = 0; j < p.index.length; j++) index[i + j] = local[p.index[j]];
      i += p.index.length;
    }
    const g = new BufferGeometry();
    g.setAttribute('position', new BufferAttribute(position.slice(0, 3 * n), 3));
    if (color) g.setAttribute('color', new BufferAttribute(color.slice(0, 3 * n), 3, true));
    g.setIndex(new BufferAttribute(index, 1));
    g.computeVertexNormals();
    g.computeBoundingSphere();
    return new Mesh(g, color ? this.coloured : this.shaded);
  }

  frameAll() {
    let r = 0; const c = new Vector3(); let n = 0;
    for (const g of this.groups.values()) {
      if (!g.mesh) continue;
      c.add(g.mesh.geometry.boundingSphere.center); n++;
    }
    if (n === 0) return;
    c.divideScalar(n);
    for (const g of this.groups.values()) {
      if (!g.mesh) continue;
      const s = g.mesh.geometry.boundingSphere;
      r = Math.max(r, s.center.distanceTo(c) + s.radius);
    }
    this.controls.target.copy(c);
    const dir = this.camera.position.clone().sub(c).normalize();
    if (!Number.isFinite(dir.x)) dir.set(0, -0.5, -1).normalize();
    this.camera.position.copy(c).addScaledVector(dir, r * 1.4);
    this.framed = true;
  }

  figures(m) {
    $('frames').textContent = String(m.frames ?? 0);
    $('lost').textContent = String(m.lost_frames ?? 0);
    $('weak').textContent = String(m.weak_frames ?? 0);
    $('fps').textContent = (m.fps ?? 0).toFixed(1);
    $('upload').textContent = rate(m.upload_bytes_per_second ?? 0);
    $('tracking').textContent = m.tracking ?? '–';
    if (m.pose) this.placeSensor(m.pose);
  }

  placeSensor(pose) {
    const matrix = new Matrix4().fromArray(pose);
    this.frustum.matrix.copy(matrix);
    const e = matrix.elements;
    if (!this.up) {
      // The sensor's image rows run down: its up is minus its y axis.
      this.up = new Vector3(-e[4], -e[5], -e[6]).normalize();
      this.camera.up.copy(this.up);
    }
    if (!this.follow) return;
    const at = new Vector3(e[12], e[13], e[14]);
    const forward = new Vector3(e[8], e[9], e[10]).normalize();
    const target = at.clone().addScaledVector(forward, 1.2);
    this.camera.position.copy(at).addScaledVector(forward, -0.8).addScaledVector(this.up, 0.5);
    this.controls.target.copy(target);
  }

  addTrail(m) {
    this.trail.length = m.from * 4;
    for (const p of m.points) this.trail.push(...p);
    const n = this.trail.length / 4;
    const line = new Float32Array(n * 3); const lost = [];
    for (let i = 0; i < n; i++) {
      line.set(this.trail.slice(4 * i, 4 * i + 3), 3 * i);
      if (this.trail[4 * i + 3] > 0) lost.push(...this.trail.slice(4 * i, 4 * i + 3));
    }
    this.trailLine.geometry.dispose();
    this.trailLine.geometry = new BufferGeometry();
    this.trailLine.geometry.setAttribute('position', new BufferAttribute(line, 3));
    this.lostPoints.geometry.dispose();
    this.lostPoints.geometry = new BufferGeometry();
    this.lostPoints.geometry.setAttribute('position', new BufferAttribute(new Float32Array(lost), 3));
  }

  showImage(kind, jpeg) {
    const img = kind === 0 ? $('status') : $('depth');
    const old = img.src;
    img.src = URL.createObjectURL(new Blob([jpeg], { type: 'image/jpeg' }));
    img.hidden = false;
    if (old.startsWith('blob:')) URL.revokeObjectURL(old);
  }

  end(summary) {
    this.ended = true;
    const server = summary.triangles;
    $('state').textContent = summary.error
      ? `ended: ${summary.error}`
      : `finished · ${server} triangles`;
    document.body.dataset.ended = String(server);
  }

  everySecond() {
    $('download').textContent = rate(this.received - this.receivedThen);
    $('received').textContent = bytes(this.received);
    this.receivedThen = this.received;
    $('drawfps').textContent = String(this.frames);
    this.frames = 0;
  }
}

function bytes(n) {
  if (n >= 1 << 20) return `${(n / (1 << 20)).toFixed(1)} MiB`;
  if (n >= 1 << 10) return `${(n / (1 << 10)).toFixed(1)} KiB`;
  return `${n} B`;
}

const rate = (n) => `${bytes(n)}/s`;

// A token pasted into the address later (`#token=T`) applies at once.
window.addEventListener('hashchange', () => { if (location.hash.includes('token=')) location.reload(); });
main();
