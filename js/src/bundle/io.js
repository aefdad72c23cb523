// Where bundle files come from and how a graph becomes a session: the only module that touches the file
// system, the network or onnxruntime's loader, so a browser build swaps in onnxruntime-web and urlLoader
// without touching the rest.
//
//   const gen = await MotionGenerator.load(fileLoader('bundles/base'))                          // Node (default)
//   const gen = await MotionGenerator.load(urlLoader('/bundles/base/'), { ort: await import('onnxruntime-web') })
//
// A loader is { where, readBytes(name) -> Promise<Uint8Array> }; `name` is a plain file name the manifest
// lists (sections.js refuses anything else), so a loader never resolves a path outside its bundle.

/** Files of a bundle folder on disk (Node). Refuses links and anything that is not a regular file. */
export function fileLoader(dir) {
  return {
    where: dir,
    async readBytes(name) {
      const { lstat, readFile } = await import('node:fs/promises');
      const { join } = await import('node:path');
      const path = join(dir, name);
      let info;
      try {
        info = await lstat(path);
      } catch (e) {
        if (e.code === 'ENOENT') throw new LoadError(`${path}: missing`);
        throw new LoadError(`${path}: cannot read it (${e.message})`);
      }
      if (!info.isFile()) throw new LoadError(`${path}: not a regular file (bundle files cannot be links or folders)`);
      return new Uint8Array(await readFile(path));
    },
  };
}

/** Files of a bundle served over HTTP(S), e.g. beside a web page; `fetchFn` for tests or custom headers. */
export function urlLoader(baseUrl, fetchFn = globalThis.fetch) {
  const base = baseUrl.endsWith('/') ? baseUrl : `${baseUrl}/`;
  return {
    where: base,
    async readBytes(name) {
      const url = `${base}${encodeURIComponent(name)}`;
      const response = await fetchFn(url);
      if (!response.ok) throw new LoadError(`${url}: HTTP ${response.status}`);
      return new Uint8Array(await response.arrayBuffer());
    },
  };
}

/** A file or URL that could not be read. */
export class LoadError extends Error {
  name = 'LoadError';
}

/** Lowercase hex SHA-256 (WebCrypto: the same call in Node 20+ and browsers). */
export async function sha256Hex(bytes) {
  const digest = await globalThis.crypto.subtle.digest('SHA-256', bytes);
  return Array.from(new Uint8Array(digest), (b) => b.toString(16).padStart(2, '0')).join('');
}

/**
 * An onnxruntime session (`ort`: onnxruntime-node or -web; `providers`: ['cpu'] in Node, ['wasm'] in a browser) for
 * one graph's bytes, with the Python runtime's options (text.py): few threads, one graph at a time, all optimisations.
 */
export async function createSession(ort, bytes, { threads, providers = ['cpu'] }) {
  const options = { executionProviders: providers, intraOpNumThreads: threads, interOpNumThreads: 1,
    executionMode: 'sequential', graphOptimizationLevel: 'all' };
  if (threads > 1) {
    // spinning workers fight the host's own threads for the cores (measured 2-3x slower on a busy machine)
    options.extra = { session: { intra_op: { allow_spinning: '0' } } };
  }
  return ort.InferenceSession.create(bytes, options);
}
