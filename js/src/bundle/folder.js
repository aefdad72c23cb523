// A mogo bundle read through a loader (io.js), trusting nothing, as runtime/mogo_runtime/bundle/folder.py:
// the manifest is parsed and checked field by field, every file the runtime reads must have the recorded size
// and sha256, and each graph session must declare the inputs and outputs the manifest promises.
//
// One difference from Python: onnxruntime's JavaScript API cannot read a graph's metadata_props, so the
// `mogo.<field>` facts in each graph are not compared with the manifest here (the I/O names, element types,
// ranks and fixed sizes are).

import { oneLine, shown } from '../checks.js';
import { sha256Hex } from './io.js';
import { graphSpec, parseManifest } from './manifest.js';
import { BundleError, sameJson } from './sections.js';

const MANIFEST_MAX_BYTES = 16 << 20;   // a real manifest is ~30 KB; refuse to read anything huge
const GRAPH_MAX_BYTES = 2 ** 31 - 1;   // protobuf's limit: onnxruntime cannot parse a larger self-contained ONNX file

export class Bundle {
  constructor(loader, manifest, verifyHashes) {
    Object.assign(this, { loader, where: loader.where, manifest, verifyHashes });
  }

  /** The bundle a loader ({where, readBytes(name, most) -> Promise<Uint8Array>}, io.js) reads, its manifest checked. */
  static async load(loader, { verifyHashes = true } = {}) {
    const where = oneLine(`${loader.where.replace(/\/$/, '')}/manifest.json`);
    let bytes;
    try {
      bytes = await loader.readBytes('manifest.json', MANIFEST_MAX_BYTES);
    } catch (e) {
      throw new BundleError(`${where}: manifest missing or unreadable (not a mogo bundle, or an export that did not finish): `
        + `${oneLine(e.message, 300)}`);
    }
    if (bytes.length > MANIFEST_MAX_BYTES) throw new BundleError(`${where}: ${bytes.length} bytes, more than a manifest can be`);
    let data;
    try {
      data = JSON.parse(new TextDecoder('utf-8', { fatal: true }).decode(bytes));
    } catch (e) {
      throw new BundleError(`${where}: not valid JSON (${oneLine(e.message, 200)})`);
    }
    return new Bundle(loader, parseManifest(data, where), verifyHashes);
  }

  /**
   * A listed file's bytes, after checking its size and (unless turned off) its sha256. A file larger than the
   * manifest says is refused before it is read.
   */
  async read(name) {
    const entry = this.manifest.files[name];
    if (!entry) throw new BundleError(`${oneLine(this.where)}: ${shown(name)} is not part of this bundle`);
    const path = this.path(name);
    if (name.endsWith('.onnx') && entry.bytes > GRAPH_MAX_BYTES) {
      throw new BundleError(`${path}: ${entry.bytes} bytes; an ONNX graph without external data is at most `
        + `${GRAPH_MAX_BYTES} bytes`);
    }
    let bytes;
    try {
      bytes = await this.loader.readBytes(name, entry.bytes);
    } catch (e) {
      throw new BundleError(`${path}: listed in manifest 'files' but cannot be read (${oneLine(e.message, 300)})`);
    }
    if (bytes.length !== entry.bytes) throw new BundleError(`${path}: size ${bytes.length} bytes, manifest says ${entry.bytes}`);
    if (this.verifyHashes && (await sha256Hex(bytes)) !== entry.sha256) {
      throw new BundleError(`${path}: sha256 does not match the manifest (file corrupted or replaced)`);
    }
    return bytes;
  }

  /** Where file `name` is, for messages (on one line, whatever the name holds). */
  path(name) { return oneLine(`${this.where.replace(/\/$/, '')}/${name}`); }

  /**
   * An onnxruntime session of `graph` declares the inputs and outputs (names; element types, ranks and fixed
   * sizes where the binding reports them) that the manifest lists: a fixed size is what a consumer allocates.
   */
  checkSession(graph, file, session, variant) {
    const spec = graphSpec(this.manifest, graph, variant);
    const field = spec === this.manifest.graphs[graph] ? `graphs.${graph}` : 'portable.step';
    const path = this.path(file);
    for (const [kind, names, metadata] of [['inputs', session.inputNames, session.inputMetadata],
      ['outputs', session.outputNames, session.outputMetadata]]) {
      const want = spec[kind].map((d) => d.name).sort(), got = [...names].sort();
      if (!sameJson(got, want)) {
        throw new BundleError(`${path}: ${kind} are ${shown(got, 200)}, manifest ${field}.${kind} lists ${shown(want, 200)}`);
      }
      if (!Array.isArray(metadata)) continue;   // older bindings: names only
      for (const d of spec[kind]) {
        const io = metadata.find((m) => m.name === d.name), what = `${path}: ${kind.slice(0, -1)} ${shown(d.name)}`;
        if (!io.isTensor || io.type !== d.dtype) {
          throw new BundleError(`${what} has type ${io.isTensor ? io.type : 'other than a tensor'}, manifest says ${d.dtype}`);
        }
        if (io.shape.length !== d.shape.length || d.shape.some((n, i) => Number.isInteger(n) && io.shape[i] !== n)) {
          throw new BundleError(`${what} has shape ${shown(io.shape, 200)}, manifest ${field} says ${shown(d.shape, 200)}`);
        }
      }
    }
  }
}
