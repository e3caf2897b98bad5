// The viewer page: pick a phantom, a capsule site and sensors, trace (POST /v1/channel), see the paths
// in 3-D and the selected sensor's power-delay profile (POST /v1/plots/pdp); locate the capsule from the traced
// first-path delays (POST /v1/localize) and draw the estimate and its error ellipsoid. State for tests:
// window.viewerState.
import { CONFIDENCE } from './ellipsoid.js';
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
  receivers: [], pdp: null, error: null, locating: false, locates: 0, fix: null, coverage: 0,
};
window.viewerState = state;
const view = new Scene3D($('scene'));
let info = null; // GET /v1/phantoms/{id}
let channel = null; // the last POST /v1/channel response
let organMeshes = {};
let pdpUrl = null;
let siteSize = 1e-3; // the site markers' radius [m]
let traced = null; // what the last trace was run with: {phantom, frequency_hz}

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
  clearFix();
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
  siteSize = markerSize(info, box);
  view.setSites(info.sites, siteSize);
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
  clearFix();
  status(`Tracing ${body.rays} rays to ${receivers.length} sensors…`);
  const started = performance.now();
  try {
    const response = await api('/v1/channel', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    });
    channel = await response.json();
    traced = { phantom: body.phantom, frequency_hz: body.frequency_hz };
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
    $('locate').disabled = !channel;
  }
}

function clearFix() {
  state.fix = null;
  $('fix').hidden = true;
  $('locate').disabled = true;
  view.clearFix();
}

/** The traced sensors' first-path delays (the earliest path of each; sensors without a path are left out)
 *  -> POST /v1/localize; the estimate, its error ellipsoid and the error against the traced capsule position. */
async function locate() {
  const method = $('locate-method').value;
  const sigma_m = Number($('locate-sigma').value) / 1000;
  const permittivity = Number($('locate-permittivity').value);
  const confidence = CONFIDENCE[$('locate-confidence').value];
  const seen = channel.profiles.filter((p) => p.paths.length);
  const body = {
    method, phantom: traced.phantom, frequency_hz: traced.frequency_hz, relative_permittivity: permittivity,
    delay_kind: 'phase', // the paths' delay_s is their phase delay (docs/localization.md, "Delay kinds")
    sensors: seen.map((p) => ({ position_m: p.position_m, delay_s: Math.min(...p.paths.map((q) => q.delay_s)), sigma_m })),
  };
  const left = channel.profiles.length - seen.length;
  state.locating = true;
  $('locate').disabled = true;
  status(`Locating from ${seen.length} first-path delays (${method})…`);
  try {
    const fix = await (await api('/v1/localize', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
    })).json();
    const truth = channel.transmitter.position_m;
    const axes_m = view.setFix(fix.position_m, fix.covariance_m2, confidence.scale, truth, 0.6 * siteSize);
    const delta = fix.position_m.map((x, k) => x - truth[k]);
    const error_m = Math.hypot(...delta);
    state.fix = {
      method: fix.method, position_m: fix.position_m, covariance_m2: fix.covariance_m2, truth_m: truth, error_m,
      sigma_m, confidence: $('locate-confidence').value, scale: confidence.scale, axes_m, sensors: seen.length,
      converged: fix.converged, drawn: view.fixReadback(),
    };
    showFix(fix, truth, delta, axes_m, confidence, sigma_m, seen.length);
    state.locates += 1;
    status(`${method}: ${(error_m * 1000).toFixed(1)} mm from the true position, ${seen.length} sensors`
      + `${left ? ` (${left} without a path left out)` : ''}.`);
  } catch (error) {
    status(`Locate failed: ${error.message}`, true);
  } finally {
    state.locating = false;
    $('locate').disabled = !channel;
  }
}

function showFix(fix, truth, delta, axes_m, confidence, sigma_m, sensors) {
  const mm = (v) => v.map((x) => (x * 1000).toFixed(1)).join(', ');
  const rms = Math.sqrt(fix.residuals_m.reduce((a, r) => a + r * r, 0) / fix.residuals_m.length);
  const rows = [
    ['method', `${fix.method}, ${sensors} sensors${fix.converged ? '' : ' (not converged)'}`],
    ['estimate [mm]', mm(fix.position_m)],
    ['true position [mm]', mm(truth)],
    ['error [mm]', `${(Math.hypot(...delta) * 1000).toFixed(1)} (${mm(delta)})`, 'error-mm'],
    [`ellipsoid semi-axes, ${confidence.label} [mm]`, axes_m.map((a) => (a * 1000).toFixed(2)).join(', ')],
    ['range sigma [mm]', (sigma_m * 1000).toFixed(2)],
    ['CRLB (3-D RMS) [mm]', fix.crlb_m === null ? '-' : (fix.crlb_m * 1000).toFixed(2)],
    ['PDOP', fix.pdop.toFixed(2)],
    ['RMS residual [mm]', (rms * 1000).toFixed(2)],
  ];
  if (fix.relative_permittivity !== null) rows.push(['fitted eps_r', fix.relative_permittivity.toFixed(1)]);
  if (fix.inside_domain === false) rows.push(['note', 'the estimate lies outside the body']);
  $('fix-table').tBodies[0].replaceChildren(...rows.map(([key, value, cls]) => {
    const row = document.createElement('tr');
    row.append(Object.assign(document.createElement('td'), { textContent: key }),
      Object.assign(document.createElement('td'), { textContent: value, className: cls || '' }));
    return row;
  }));
  $('fix').hidden = false;
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

/** The design layer (docs/design.md): a coverage job's candidates on the skin, coloured by the chosen metric
 *  (its median over the capsule positions; the fraction of positions with a direct path). */
async function showCoverage() {
  const id = $('coverage-id').value.trim();
  const metric = $('coverage-metric').value;
  try {
    const map = await api(`/v1/design/coverage/${encodeURIComponent(id)}/map?metric=${metric}`).then((r) => r.json());
    const scale = metric.endsWith('delay_s') ? 1e9 : 1;
    const values = map.values.map((v) => (v === null ? null : v * scale));
    const finite = values.filter((v) => v !== null);
    const lo = finite.length ? Math.min(...finite) : 0;
    const hi = finite.length ? Math.max(...finite) : 1;
    const shown = view.setCoverage(map.candidates_m, values, lo, hi, siteSize * 0.6);
    state.coverage = shown;
    $('coverage-label').textContent = $('coverage-metric').selectedOptions[0].textContent;
    $('coverage-min').textContent = lo.toFixed(metric === 'direct_path' ? 2 : 1);
    $('coverage-max').textContent = hi.toFixed(metric === 'direct_path' ? 2 : 1);
    $('coverage-scale').hidden = false;
    status(`Coverage ${id}: ${shown} candidates coloured by ${metric}, ${values.length - finite.length} without a path.`);
  } catch (error) {
    status(`Coverage failed: ${error.message}`, true);
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
$('locate').addEventListener('click', locate);
$('locate-confidence').replaceChildren(...Object.entries(CONFIDENCE).map(([key, c]) => new Option(c.label, key)));
$('pdp-sensor').addEventListener('change', (e) => showProfile(e.target.value));
$('coverage-show').addEventListener('click', showCoverage);
$('coverage-clear').addEventListener('click', () => { view.clearCoverage(); $('coverage-scale').hidden = true; });

loadPhantoms().catch((error) => status(`Loading failed: ${error.message}`, true));
