// Where bundle files come from and how a graph becomes a session: the only module that touches the file
// system, the network or onnxruntime's loader, so a browser build swaps in onnxruntime-web and urlLoader
// without touching the rest.
//
//   const gen = await MotionGenerator.load(fileLoader('bundles/base'))                          // Node (default)
//   const gen = await MotionGenerator.load(urlLoader('/bundles/base/'), { ort: await import('onnxruntime-web') })
//
// A loader is { where, readBytes(name, most) -> Promise<Uint8Array> }; `name` is a plain file name the manifest
// lists (sections.js refuses anything else), so a loader never resolves a path outside its bundle. `most` is the
// size the file may have at most (the manifest's, or the manifest's own limit): a larger file is refused before
// it is read, and no more than most + 1 bytes are read whatever a file system or a server says the size is
// (runtime/mogo_runtime/checks.py read_file).

import { oneLine } from '../checks.js';

/** Files of a bundle folder on disk (Node): regular files only, never a link, folder, device or pipe. */
export function fileLoader(dir) {
  return {
    where: dir,
    async readBytes(name, most) {
      checkMost(most);
      const { constants, open } = await import('node:fs/promises');
      const path = `${dir.replace(/[/\\]$/, '')}/${name}`, where = oneLine(path);
      let file;
      try {
        // O_NONBLOCK: a FIFO opens without waiting for a writer (then is refused); O_NOFOLLOW: a link is refused
        file = await open(path, constants.O_RDONLY | (constants.O_NONBLOCK ?? 0) | (constants.O_NOFOLLOW ?? 0));
      } catch (e) {
        const why = { ENOENT: 'missing', ELOOP: 'a link (bundle files cannot be links)' }[e.code];
        throw new LoadError(`${where}: ${why ?? `cannot read it (${oneLine(e.message, 200)})`}`);
      }
      try {
        const info = await file.stat();
        if (!info.isFile()) {
          throw new LoadError(`${where}: not a regular file (${info.isDirectory() ? 'a folder' : 'a device or a pipe'})`);
        }
        if (info.size > most) throw new LoadError(`${where}: ${inBytes(info.size)}, more than the ${inBytes(most)} expected`);
        // one byte more than allowed tells a file longer than its size says (a file being written, /proc)
        const buffer = new Uint8Array(most + 1);
        let size = 0;
        while (size < buffer.length) {
          const { bytesRead } = await file.read(buffer, size, Math.min(buffer.length - size, 1 << 30), null);
          if (!bytesRead) break;
          size += bytesRead;
        }
        if (size > most) throw new LoadError(`${where}: more than the ${inBytes(most)} expected`);
        return buffer.subarray(0, size);
      } finally {
        await file.close();
      }
    },
  };
}

/**
 * Files of a bundle served over HTTP(S), e.g. beside a web page; `fetchFn` for tests or custom headers. A declared
 * Content-Length over `most` is refused unread, and the body is read no further than most + 1 bytes (a `fetchFn`
 * whose response has no readable `body`, only arrayBuffer(), is read whole and its length checked by the bundle).
 */
export function urlLoader(baseUrl, fetchFn = globalThis.fetch) {
  const base = baseUrl.endsWith('/') ? baseUrl : `${baseUrl}/`;
  return {
    where: base,
    async readBytes(name, most) {
      checkMost(most);
      const url = `${base}${encodeURIComponent(name)}`;
      const response = await fetchFn(url);
      if (!response.ok) throw new LoadError(`${url}: HTTP ${response.status}`);
      const declared = Number(response.headers?.get('content-length') ?? NaN);
      if (declared > most) throw new LoadError(`${url}: ${inBytes(declared)}, more than the ${inBytes(most)} expected`);
      if (!response.body?.getReader) return new Uint8Array(await response.arrayBuffer());
      const reader = response.body.getReader(), chunks = [];
      for (let size = 0, chunk; !(chunk = await reader.read()).done;) {
        size += chunk.value.length;
        if (size > most) {
          reader.cancel().catch(() => {});   // the rest of the body is not wanted
          throw new LoadError(`${url}: more than the ${inBytes(most)} expected`);
        }
        chunks.push(chunk.value);
      }
      return concat(chunks);
    },
  };
}

const inBytes = (n) => `${n.toLocaleString('en-US')} bytes`;

/** Typed arrays of one kind (bytes, floats) joined end to end, into a new array of that kind (none: no bytes). */
export function concat(arrays) {
  const out = new (arrays[0]?.constructor ?? Uint8Array)(arrays.reduce((n, a) => n + a.length, 0));
  let at = 0;
  for (const a of arrays) {
    out.set(a, at);
    at += a.length;
  }
  return out;
}

function checkMost(most) {
  if (!Number.isSafeInteger(most) || most < 0) {
    throw new TypeError(`readBytes(name, most): most must be a size in bytes, got ${most}`);
  }
}

/** A file or URL that could not be read. */
export class LoadError extends Error {
  name = 'LoadError';
}

/** SHA-256, 32 bytes (WebCrypto: the same call in Node 20+ and browsers). */
export async function sha256(bytes) {
  return new Uint8Array(await globalThis.crypto.subtle.digest('SHA-256', bytes));
}

/** Lowercase hex SHA-256. */
export async function sha256Hex(bytes) {
  return toHex(await sha256(bytes));
}

/** Bytes as lowercase hex, two digits each. */
export const toHex = (bytes) => Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');

/**
 * An onnxruntime session (`ort`: onnxruntime-node or -web; `providers`: ['cpu'] in Node, ['wasm'] in a browser) for
 * one graph's bytes, with the Python runtime's options (text.py): few threads, one graph at a time, all optimisations.
 */
export async function createSession(ort, bytes, { threads, providers = ['cpu'] }) {
  const options = { executionProviders: providers, intraOpNumThreads: threads, interOpNumThreads: 1,
    executionMode: 'sequential', graphOptimizationLevel: 'all', logSeverityLevel: 3 };   // errors are ours to report
  if (threads > 1) {
    // spinning workers fight the host's own threads for the cores (measured 2-3x slower on a busy machine)
    options.extra = { session: { intra_op: { allow_spinning: '0' } } };
  }
  return ort.InferenceSession.create(bytes, options);
}
