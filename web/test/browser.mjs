// What the browser tests share: the server, downloads, the skeleton's pixels in screenshots, token rows.

import { spawn } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';

/** web/serve.py on a free port; resolves once it prints its URL. */
export function serve(python, root, mounts) {
  return new Promise((resolve, reject) => {
    const proc = spawn(python, [join(root, 'web/serve.py'), '--port', '0', '--page', '', ...mounts], { stdio: ['ignore', 'pipe', 'inherit'] });
    let out = '';
    proc.stdout.on('data', (chunk) => {
      out += chunk;
      const m = out.match(/(http:\/\/\S+)/);
      if (m) resolve({ process: proc, url: m[1].endsWith('/') ? m[1] : `${m[1]}/` });
    });
    proc.on('exit', (code) => reject(new Error(`web/serve.py exited with ${code}: ${out}`)));
  });
}

/** The text of the file that a click on `button` downloads. */
export async function downloaded(page, button) {
  const [download] = await Promise.all([page.waitForEvent('download'), page.click(button)]);
  const path = await download.path();
  return readFileSync(path, 'utf8');
}

/**
 * Pixels of the skeleton's colours in PNG screenshots, decoded by the browser: the only saturated colours on
 * screen are its left (blue), right (orange) and centre (yellow) parts. `moved[i]`: pixels that are skeleton in
 * one of shots i, i + 1 and not in the other.
 */
export async function skeletonPixels(page, pngs) {
  return page.evaluate(async (list) => {
    const masks = [], shots = [];
    let width = 0, height = 0;
    for (const b64 of list) {
      const img = new Image();
      img.src = `data:image/png;base64,${b64}`;
      await img.decode();
      ({ width, height } = img);
      const canvas = new OffscreenCanvas(width, height);
      const ctx = canvas.getContext('2d');
      ctx.drawImage(img, 0, 0);
      const d = ctx.getImageData(0, 0, width, height).data;
      const mask = new Uint8Array(width * height);
      const count = { skeleton: 0, left: 0, right: 0, centre: 0 };
      for (let i = 0; i < mask.length; i++) {
        const r = d[4 * i] / 255, g = d[4 * i + 1] / 255, b = d[4 * i + 2] / 255;
        const max = Math.max(r, g, b), min = Math.min(r, g, b);
        if (max < 0.3 || (max - min) / max < 0.45) continue;   // dark or grey: background, grid, panel
        let hue = max === r ? ((g - b) / (max - min)) * 60 : max === g ? (2 + (b - r) / (max - min)) * 60 : (4 + (r - g) / (max - min)) * 60;
        if (hue < 0) hue += 360;
        const side = hue >= 190 && hue <= 225 ? 'left' : hue >= 12 && hue < 36 ? 'right' : hue >= 36 && hue <= 60 ? 'centre' : null;
        if (!side) continue;
        mask[i] = 1;
        count.skeleton += 1;
        count[side] += 1;
      }
      masks.push(mask);
      shots.push(count);
    }
    const moved = [];
    for (let k = 1; k < masks.length; k++) {
      let n = 0;
      for (let i = 0; i < masks[k].length; i++) n += masks[k][i] !== masks[k - 1][i];
      moved.push(n);
    }
    return { width, height, shots, moved };
  }, pngs.map((b) => b.toString('base64')));
}

/** How many leading rows two token lists share. */
export function sharedPrefix(a, b) {
  let n = 0;
  while (n < a.length && n < b.length && a[n].join() === b[n].join()) n += 1;
  return n;
}

/** Flat tokens -> rows of `levels`. */
export function rows(flat, levels) {
  return Array.from({ length: flat.length / levels }, (_, t) => flat.slice(t * levels, (t + 1) * levels));
}
