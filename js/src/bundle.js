// A mogo bundle read through a loader (io.js), trusting nothing, as runtime/mogo_runtime/bundle.py:
// the manifest is parsed and checked field by field, every file the runtime reads must have the recorded size
// and sha256, and each graph session must declare the inputs and outputs the manifest promises.
//
// One difference from Python: onnxruntime's JavaScript API cannot read a graph's metadata_props, so the
// `mogo.<field>` facts in each graph are not compared with the manifest here (the I/O names, element types,
// ranks and the logits' width are).

import { BundleError, graphSpec, parseManifest } from './manifest.js';
import { sha256Hex } from './io.js';

const MANIFEST_MAX_BYTES = 16 << 20;   // a real manifest is ~30 KB; refuse to parse anything huge

export class Bundle {
  constructor(loader, manifest, verifyHashes) {
    this.loader = loader;
    this.where = loader.where;
    this.manifest = manifest;
    this.verifyHashes = verifyHashes;
  }

  /**
   * @param {{where: string, readBytes: (name: string) => Promise<Uint8Array>}} loader
   * @param {{verifyHashes?: boolean}} [options]
   */
  static async load(loader, { verifyHashes = true } = {}) {
    const where = `${loader.where.replace(/\/$/, '')}/manifest.json`;
    let bytes;
    try {
      bytes = await loader.readBytes('manifest.json');
    } catch (e) {
      throw new BundleError(`${where}: manifest missing or unreadable (not a mogo bundle, or an export that did not finish): ${e.message}`);
    }
    if (bytes.length > MANIFEST_MAX_BYTES) throw new BundleError(`${where}: ${bytes.length} bytes, more than a manifest can be`);
    let data;
    try {
      data = JSON.parse(new TextDecoder('utf-8', { fatal: true }).decode(bytes));
    } catch (e) {
      throw new BundleError(`${where}: not valid JSON (${e.message})`);
    }
    return new Bundle(loader, parseManifest(data, where), verifyHashes);
  }

  /** A listed file's bytes, after checking its size and (unless turned off) its sha256. */
  async read(name) {
    const entry = this.manifest.files[name];
    if (!entry) throw new BundleError(`${this.where}: ${JSON.stringify(name)} is not part of this bundle`);
    const path = `${this.where.replace(/\/$/, '')}/${name}`;
    let bytes;
    try {
      bytes = await this.loader.readBytes(name);
    } catch (e) {
      throw new BundleError(`${path}: listed in manifest 'files' but cannot be read (${e.message})`);
    }
    if (bytes.length !== entry.bytes) throw new BundleError(`${path}: size ${bytes.length} bytes, manifest says ${entry.bytes}`);
    if (this.verifyHashes && (await sha256Hex(bytes)) !== entry.sha256) {
      throw new BundleError(`${path}: sha256 does not match the manifest (file corrupted or replaced)`);
    }
    return bytes;
  }

  /**
   * An onnxruntime session of `graph` declares the inputs and outputs (names; element types and ranks where
   * the binding reports them) that the manifest lists.
   */
  checkSession(graph, file, session, variant) {
    const spec = graphSpec(this.manifest, graph, variant);
    const path = `${this.where.replace(/\/$/, '')}/${file}`;
    for (const [kind, names, metadata] of [['inputs', session.inputNames, session.inputMetadata],
      ['outputs', session.outputNames, session.outputMetadata]]) {
      const declared = spec[kind];
      const want = declared.map((d) => d.name).sort();
      if (JSON.stringify([...names].sort()) !== JSON.stringify(want)) {
        throw new BundleError(`${path}: ${kind} are ${JSON.stringify([...names].sort())}, manifest graphs.${graph}.${kind} lists ${JSON.stringify(want)}`);
      }
      if (!Array.isArray(metadata)) continue;   // older bindings: names only
      for (const d of declared) {
        const got = metadata.find((m) => m.name === d.name);
        if (!got || !got.isTensor) continue;
        if (got.type !== d.dtype) {
          throw new BundleError(`${path}: ${kind.slice(0, -1)} ${JSON.stringify(d.name)} has type ${got.type}, manifest says ${d.dtype}`);
        }
        if (got.shape.length !== d.shape.length) {
          throw new BundleError(`${path}: ${kind.slice(0, -1)} ${JSON.stringify(d.name)} has rank ${got.shape.length}, `
            + `manifest shape is ${JSON.stringify(d.shape)}`);
        }
      }
    }
  }
}
