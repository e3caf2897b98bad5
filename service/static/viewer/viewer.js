// The viewer page: pick a phantom, a capsule site and sensors, trace (POST /v1/channel), see the paths
// in 3-D and the selected sensor's power-delay profile (POST /v1/plots/pdp). State for tests: window.viewerState.
import { tissueColour } from './palette.js';
import { Scene3D } from './scene.js';

const $ = (id) => document.getElementById(id);
const GAIN_RANGE_DB = 60; // paths are coloured over the strongest path's gain minus this
const MAX_PRESELECTED_SENSORS = 12;
const POSITION = '(a position)'; // the capsule select's entry for a position typed in mm
const AXES = ['x', 'y', 'z'];
const KIND_LETTER = { reflection: 'R', refraction: 'T', total_internal_reflection: 'TIR' };

const state = {
  phantom: null, ready: false, organs: 0, sites: 0, tracing: false, traces: 0, paths: 0, transmitter: null,
  receivers: [], pdp: null, error: null,
};
window.viewerState = state;
const view = new Scene3D($('scene'));
let info = null; // GET /v1/phantoms/{id}
let channel = null; // the last POST /v1/channel response
let organMeshes = {};
let pdpUrl = null;

async function api(path, options = {}) {
  const response = await fetch(path, options);
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    try {
      message = (await response.json()).detail.map((d) => `${d.loc.join('.')}: ${d.msg}`).join('; ');
    } catch { /* not the API's error JSON: keep the status line */ }
    throw new Error(message);
  }
  return response;
}

function status(text, isError = false) {
  $('status').textContent = text;
  $('status').classList.toggle('error', isError);
  state.error = isError ? text : null;
}

function sitesOf(kind) {
  return Object.entries(info.sites).filter(([, s]) => s.kind === kind).map(([name]) => name);
}

function checkedSensors() {
  return new Set([...$('sensors').querySelectorAll('input:checked')].map((c) => c.value));
}

function markSites() {
  view.markSites($('capsule').value, checkedSensors());
}

async function loadPhantoms() {
  const { phantoms } = await (await api('/v1/phantoms')).json();
  const select = $('phantom');
  select.replaceChildren(...phantoms.map((p) => new Option(p.builtin ? p.name : `${p.name} (uploaded, ${p.id})`, p.id)));
  const wanted = new URLSearchParams(location.search).get('phantom');
  const ids = phantoms.map((p) => p.id);
  select.value = ids.includes(wanted) ? wanted : ids.includes('torso') ? 'torso' : ids[0];
  await loadPhantom(select.value);
}

async function loadPhantom(id) {
  Object.assign(state, { phantom: id, ready: false, paths: 0, receivers: [], pdp: null });
  channel = null;
  showResults();
  status(`Loading phantom ${id}…`);
  const [described, manifest, glb] = await Promise.all([
    api(`/v1/phantoms/${id}`).then((r) => r.json()),
    api(`/v1/phantoms/${id}/manifest`).then((r) => r.json()),
    api(`/v1/phantoms/${id}/mesh`).then((r) => r.arrayBuffer()),
  ]);
  info = described;
  organMeshes = await view.loadOrgans(glb, info.organs, manifest.units === 'mm' ? 1e-3 : 1);
  view.clearPaths();
  const box = framingBox(info);
  view.setSites(info.sites, markerSize(info, box));
  fillSites();
  fillLegend();
  view.fit(box);
  Object.assign(state, { organs: Object.keys(organMeshes).length, sites: Object.keys(info.sites).length, ready: true });
  const capsules = sitesOf('capsule').length;
  const sensors = sitesOf('sensor').length;
  status(`${info.name}: ${info.organs.length} organs, ${info.triangles} triangles, ${capsules} capsule and `
    + `${sensors} sensor sites.${sensors ? '' : ' Tracing needs a sensor site.'}`);
}

/** The phantom's bounds, or, when the phantom dwarfs its sites (a slab, a half-space), the sites' box plus 10 cm. */
function framingBox(phantom) {
  const points = Object.values(phantom.sites).map((s) => s.position_m);
  if (!points.length) return phantom.bounds_m;
  const lo = [0, 1, 2].map((k) => Math.min(...points.map((p) => p[k])) - 0.05);
  const hi = [0, 1, 2].map((k) => Math.max(...points.map((p) => p[k])) + 0.05);
  const diagonal = (b) => Math.hypot(...[0, 1, 2].map((k) => b[1][k] - b[0][k]));
  return diagonal(phantom.bounds_m) > 4 * diagonal([lo, hi]) ? [lo, hi] : phantom.bounds_m;
}

/** Marker radius: 1.2 % of the view, at most a third of the closest two sites' distance. */
function markerSize(phantom, box) {
  const points = Object.values(phantom.sites).map((s) => s.position_m);
  let closest = Infinity;
  for (let i = 0; i < points.length; i++) {
    for (let j = i + 1; j < points.length; j++) closest = Math.min(closest, Math.hypot(...[0, 1, 2].map((k) => points[i][k] - points[j][k])));
  }
  const extent = Math.hypot(...[0, 1, 2].map((k) => box[1][k] - box[0][k]));
  return Math.max(Math.min(0.012 * extent, closest / 3), 1e-4);
}

/** The transmitter of a channel request: the picked capsule site, or the typed position. */
function transmitter() {
  if ($('capsule').value !== POSITION) return { site: $('capsule').value };
  return { position_m: AXES.map((a) => Number($(`capsule-${a}`).value) / 1000) };
}

function capsuleChanged() {
  const typed = $('capsule').value === POSITION;
  $('capsule-position').hidden = !typed;
  const site = info.sites[$('capsule').value];
  if (site) AXES.forEach((a, k) => { $(`capsule-${a}`).value = (site.position_m[k] * 1000).toFixed(1); });
  markSites();
}

function fillSites() {
  const capsules = sitesOf('capsule');
  $('capsule').replaceChildren(...capsules.map((name) => new Option(name, name)), new Option(POSITION, POSITION));
  if (!capsules.length) {
    const centre = AXES.map((a, k) => (info.bounds_m[0][k] + info.bounds_m[1][k]) / 2);
    AXES.forEach((a, k) => { $(`capsule-${a}`).value = (centre[k] * 1000).toFixed(1); });
  }
  capsuleChanged();
  $('sensors').replaceChildren(...sitesOf('sensor').map((name, i) => {
    const label = document.createElement('label');
    const box = Object.assign(document.createElement('input'), { type: 'checkbox', value: name, checked: i < MAX_PRESELECTED_SENSORS });
    box.addEventListener('change', markSites);
    label.append(box, name);
    return label;
  }));
  $('trace').disabled = !sitesOf('sensor').length;
  markSites();
}

function fillLegend() {
  const groups = new Map();
  for (const organ of info.organs) {
    const key = organ.tissue || `eps_r ${organ.relative_permittivity}, sigma ${organ.conductivity_s_per_m} S/m`;
    if (!groups.has(key)) groups.set(key, { colour: tissueColour(organ.tissue, organ.name), organs: [] });
    groups.get(key).organs.push(organ.name);
  }
  $('legend').replaceChildren(...[...groups].map(([key, group]) => {
    const item = document.createElement('li');
    const swatch = Object.assign(document.createElement('span'), { className: 'swatch' });
    swatch.style.background = group.colour;
    const names = Object.assign(document.createElement('div'), { className: 'organs', textContent: group.organs.join(', ') });
    item.append(swatch, key, names);
    item.addEventListener('click', () => {
      const visible = item.classList.toggle('off') === false;
      group.organs.forEach((name) => (organMeshes[name] || []).forEach((m) => { m.visible = visible; }));
      view.render();
    });
    return item;
  }));
}

async function trace() {
  const receivers = [...checkedSensors()];
  if (!receivers.length) return status('Pick at least one sensor.', true);
  const body = {
    phantom: state.phantom,
    frequency_hz: Number($('frequency').value) * 1e6,
    transmitter: transmitter(),
    receivers: receivers.map((site) => ({ site })),
    rays: Number($('rays').value),
    max_interactions: Number($('interactions').value),
  };
  state.tracing = true;
  $('trace').disabled = true;
  status(`Tracing ${body.rays} rays to ${receivers.length} sensors…`);
  const started = performance.now();
  try {
    const response = await api('/v1/channel', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    });
    channel = await response.json();
    const gains = channel.profiles.flatMap((p) => p.paths.map((q) => q.gain_db));
    const high = gains.length ? Math.max(...gains) : 0;
    view.setPaths(channel, high - GAIN_RANGE_DB, high);
    Object.assign(state, {
      paths: view.pathCount(), traces: state.traces + 1, transmitter: channel.transmitter.position_m,
      receivers: channel.profiles.map((p) => ({ receiver: p.receiver, paths: p.paths.length })),
    });
    $('gain-min').textContent = `${(high - GAIN_RANGE_DB).toFixed(0)} dB`;
    $('gain-max').textContent = `${high.toFixed(1)} dB`;
    const seconds = ((performance.now() - started) / 1000).toFixed(2);
    status(`${channel.stats.paths_found} paths to ${receivers.length} sensors from ${channel.stats.rays_launched} `
      + `rays (trace ${channel.stats.elapsed_s.toFixed(2)} s, ${seconds} s with the transfer).`);
    showResults();
  } catch (error) {
    status(`Trace failed: ${error.message}`, true);
  } finally {
    state.tracing = false;
    $('trace').disabled = false;
  }
}

function showResults() {
  $('gain-scale').hidden = !channel;
  const select = $('pdp-sensor');
  const profiles = channel ? channel.profiles : [];
  select.replaceChildren(...profiles.map((p) => new Option(`${p.receiver} (${p.paths.length} paths)`, p.receiver)));
  const first = profiles.find((p) => p.paths.length);
  if (first) select.value = first.receiver;
  showProfile(select.value || null);
}

async function showProfile(receiver) {
  const profile = channel?.profiles.find((p) => p.receiver === receiver);
  view.focus(profile ? receiver : null, null);
  const rows = (profile?.paths || []).map((path, k) => {
    const row = document.createElement('tr');
    const kinds = path.interactions.map((i) => KIND_LETTER[i.kind]).join('-') || 'direct';
    for (const text of [k, (path.delay_s * 1e9).toFixed(4), path.gain_db.toFixed(1), kinds]) {
      row.append(Object.assign(document.createElement('td'), { textContent: text }));
    }
    row.addEventListener('click', () => {
      $('paths').querySelectorAll('tr.picked').forEach((r) => r.classList.remove('picked'));
      row.classList.add('picked');
      view.focus(receiver, [channel.transmitter.position_m, ...path.interactions.map((i) => i.point_m), profile.position_m]);
    });
    return row;
  });
  $('paths').tBodies[0].replaceChildren(...rows);
  if (pdpUrl) URL.revokeObjectURL(pdpUrl);
  pdpUrl = null;
  $('pdp').removeAttribute('src');
  state.pdp = null;
  if (!profile || !profile.paths.length) return;
  try {
    const response = await api('/v1/plots/pdp', {
      method: 'POST',
      headers: { 'Content-Type': 'application/json', Accept: 'image/svg+xml' },
      body: JSON.stringify({ profile, relative_permittivity: 27.9, width_in: 5.2, height_in: 3.6 }),
    });
    pdpUrl = URL.createObjectURL(await response.blob());
    $('pdp').src = pdpUrl;
    await $('pdp').decode();
    state.pdp = receiver;
  } catch (error) {
    status(`Power-delay profile failed: ${error.message}`, true);
  }
}

// pick sites in the scene: a click (not a drag) on a marker
let down = null;
view.renderer.domElement.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
view.renderer.domElement.addEventListener('pointerup', (e) => {
  if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;
  const site = view.pick(e);
  if (!site) return;
  if (site.kind === 'capsule') {
    $('capsule').value = site.name;
    capsuleChanged();
  } else {
    const box = $('sensors').querySelector(`input[value="${CSS.escape(site.name)}"]`);
    box.checked = !box.checked;
  }
  markSites();
  status(`${site.kind} site ${site.name}`);
});

$('phantom').addEventListener('change', (e) => loadPhantom(e.target.value).catch((err) => status(`Loading failed: ${err.message}`, true)));
$('capsule').addEventListener('change', capsuleChanged);
$('all-sensors').addEventListener('click', () => { $('sensors').querySelectorAll('input').forEach((b) => { b.checked = true; }); markSites(); });
$('no-sensors').addEventListener('click', () => { $('sensors').querySelectorAll('input').forEach((b) => { b.checked = false; }); markSites(); });
$('trace').addEventListener('click', trace);
$('pdp-sensor').addEventListener('change', (e) => showProfile(e.target.value));

loadPhantoms().catch((error) => status(`Loading failed: ${error.message}`, true));
