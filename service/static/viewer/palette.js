// Colours of the viewer: tissues (by Gabriel 1996 tissue name) and path gains (a bright ramp for a dark background).

const TISSUE_COLOURS = {
  skin: '#e0ac8b', fat: '#f2d46b', muscle: '#c0392b', stomach: '#e67e9a', small_intestine: '#f39c4a',
  colon: '#a0522d', liver: '#8e2a1e', kidney: '#8e44ad', spleen: '#6c3483', heart: '#a93226',
  lung: '#85c1e9', bone: '#ecf0f1', blood: '#b03a2e', aorta: '#b03a2e', gall_bladder: '#27ae60',
  bladder: '#f7dc6f', cartilage: '#bdc3c7', tendon: '#bdc3c7', nerve: '#d5dbdb',
};

function hashHue(text) {
  let h = 0;
  for (const c of text) h = (h * 31 + c.charCodeAt(0)) >>> 0;
  return h % 360;
}

/** CSS colour of an organ: its tissue's (matched on the name's leading words), else one hashed from a key. */
export function tissueColour(tissue, key) {
  if (tissue) {
    const match = Object.keys(TISSUE_COLOURS).filter((t) => tissue.startsWith(t)).sort((a, b) => b.length - a.length)[0];
    if (match) return TISSUE_COLOURS[match];
  }
  return `hsl(${hashHue(tissue || key)}, 55%, 60%)`;
}

// the gain ramp, weakest to strongest (viewer.css draws the gain scale with the same stops)
const RAMP = [[0x4a, 0x5c, 0xff], [0x00, 0xc2, 0xe0], [0x5f, 0xe3, 0x5a], [0xff, 0xe1, 0x4d], [0xff, 0x4d, 0x2e]];

/** [r, g, b] in 0..1 of t in 0..1 (clamped) on the gain ramp. */
export function gainColour(t) {
  const x = Math.min(Math.max(t, 0), 1) * (RAMP.length - 1);
  const i = Math.min(Math.floor(x), RAMP.length - 2);
  const f = x - i;
  return RAMP[i].map((c, k) => (c + f * (RAMP[i + 1][k] - c)) / 255);
}
