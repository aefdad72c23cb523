// Endless streams (runtime/mogo_runtime/endless.py; docs/bundle.md, "Endless streams"): a stream never ends by
// itself, follows a new prompt from the next token, and keeps a bounded context. Its context is its prompt's
// prefix (BOS) plus motion tokens, rebuilt (fed from an empty cache as [BOS, kept tokens]) when:
// - the prompt changed: nothing kept (the new prompt starts a motion as it would alone); so too when one action of
//   a prompt of several (plan.js) ends (END) or has run its stated length, and the next one starts;
// - level 0 picked END: the motion ended where a clip would end; that pick is dropped (its draws stay
//   consumed), the prompt starts again with nothing kept, and the step picks again, END forbidden;
// - the context holds window + refresh motion tokens for the COMPACTIONS + 1-th time: the last `window` are kept.
// The first COMPACTIONS times it is compacted instead: the prefix and the last window - 1 cached steps stay as they
// were computed (moved to slots 1 .. window - 1) and the newest pick is fed at slot `window`, one step row where a
// rebuild feeds window + 1. So up to its first END or compaction a stream computes exactly what generateTokens
// computes. endless.py says why.

import { shown } from './checks.js';
import { PCG64 } from './pcg64.js';
import { StepPolicy } from './policy.js';

export const COMPACTIONS = 3;   // compactions of a full context before it is rebuilt (endless.py)

/**
 * One endless stream's token state: the step rows it is conditioned on, its random generator, its recent
 * tokens, and what its next step feeds (`plan`), given the pick it then `accept`s.
 */
export class StreamContext {
  constructor(policy, emb, seed, spec, controlDim = 0, limits = null) {
    this.policy = policy;
    this.window = spec.window;
    this.span = spec.window + spec.refresh;
    // the tokens a context's numbers depend on, plus the newest pick (what a restored Python stream replays)
    this.keep = this.span + COMPACTIONS * (spec.refresh + 1);
    this.rng = new PCG64(seed);
    this.history = new Int32Array(this.keep * policy.dims.numLevels);   // token t at slot t % keep
    // with control (a model that has it): the control each token was picked with, as the history holds tokens, so
    // a rebuilt context reads what it read the first time; and the control of the next token (`steer`)
    this.controlDim = controlDim;
    this.controls = controlDim ? new Float32Array(this.keep * controlDim) : null;
    this.control = controlDim ? new Float32Array(controlDim) : null;
    this.last = null;       // the last token picked
    this.count = 0;         // tokens picked
    this.cached = 0;        // motion tokens in the context after its prefix
    this.compactions = 0;   // of the context since it was last fed from an empty cache
    this.motion = 0;        // tokens since the motion (re)started
    this.restarts = 0;      // motions ended by END and started again
    this.condition(emb, limits);
  }

  /**
   * Follow the prompt of embeddings `emb` (P, text_dim) from the next token on; nothing is kept. P > 1: a prompt of
   * several actions (plan.js), played in order, action i for limits[i] tokens, or (null) until the model ends it, at
   * most the longest motion the model was trained on; the last one is then held as a prompt of one action is: by
   * restarting it at END.
   */
  condition(emb, limits = null) {
    const actions = actionsOf(emb, limits, this.policy.dims.textDim);
    this.parts = actions.parts;
    this.limits = actions.limits;
    this.part = 0;             // the action played
    this.finishedAt = null;    // the token count when the last action first ended
    this.starts = [this.count];   // the token each action started at
    this.#startPart();
  }

  #startPart() {
    this.rowsEmb = this.policy.condition(this.parts[this.part]);   // (rows, text_dim)
    this.restart = true;
    this.inPart = 0;
  }

  /** The action played has run its course (stated duration, or as long as the model's longest motion); a lone action
   * runs until the model ends it. */
  #partOver() {
    let limit = this.limits[this.part];
    if (limit === null && this.part + 1 < this.parts.length) limit = this.policy.dims.maxTokens;
    return limit !== null && this.inPart >= limit;
  }

  #nextPart() {
    if (this.part + 1 < this.parts.length) {
      this.part += 1;
      this.starts.push(this.count);
    } else if (this.finishedAt === null) this.finishedAt = this.count;
    this.#startPart();
  }

  /** Whether the last action has ended once (it is then held, started again as the model ends it). */
  get finished() { return this.finishedAt !== null; }

  /** END may be picked once the motion has a token: never as a motion's first, so never twice in a row. */
  get mayEnd() { return this.motion >= 1; }

  /** The control vector (controlDim) the next token is picked with (control/): a new array, never changed after. */
  steer(control) { this.control = Float32Array.from(control); }

  /** [first, count]: a compaction moves cache slots first .. first + count - 1 (the last window - 1 of a full
   * context) to slots 1 .. count; slot 0, the prefix, stays. */
  get compaction() { return [this.span - this.window + 2, this.window - 1]; }

  /**
   * -> {tokens (S, L) the next step feeds, controls (S, controlDim) or null without control, fresh: whether they
   * start a new context, compact: whether the cache is compacted before they are fed}. A new context is BOS and the
   * last n picked tokens: n = 0 after a new prompt or END, `window` once the context holds window + refresh tokens for
   * the COMPACTIONS + 1-th time; otherwise the step feeds the last pick, after compacting a full context. Position i
   * of a new context picks token count - n + i, so it reads that token's control (the last: `control`).
   */
  plan() {
    const full = this.cached === this.span;
    if (!(this.restart || (full && this.compactions === COMPACTIONS))) {
      if (full) this.compactions += 1;
      this.cached = full ? this.window : this.cached + 1;
      return { tokens: this.last, controls: this.control, fresh: false, compact: full };
    }
    const L = this.policy.dims.numLevels, C = this.controlDim, n = this.restart ? 0 : this.window;
    const tokens = new Int32Array((n + 1) * L).fill(this.policy.dims.bosId);
    const controls = this.control && new Float32Array((n + 1) * C);
    for (let i = 0; i < n; i++) {   // the last n, oldest first
      const slot = (this.count - n + i) % this.keep;
      tokens.set(this.history.subarray(slot * L, (slot + 1) * L), (i + 1) * L);
      controls?.set(this.controls.subarray(slot * C, (slot + 1) * C), i * C);
    }
    controls?.set(this.control, n * C);
    this.cached = n;
    this.compactions = 0;
    this.restart = false;
    if (n === 0) this.motion = 0;
    return { tokens, controls, fresh: true, compact: false };
  }

  /**
   * The step's pick (L) -> whether it is the stream's next token. END is not: the action ended, so the next one
   * starts (the last action, or one held for its stated duration, starts again), and the step picks again.
   */
  accept(picked) {
    if (picked[0] === this.policy.dims.endId) {
      const lone = this.limits[this.part] === null;   // played until the model ends it
      if (lone && this.part + 1 < this.parts.length) {
        this.#nextPart();           // the action ended: the next one starts
      } else {                      // the last action, or one held for its stated duration, starts again
        this.restarts += 1;
        this.restart = true;
        if (this.part + 1 === this.parts.length && this.finishedAt === null && lone) this.finishedAt = this.count;
      }
      return false;
    }
    this.history.set(picked, (this.count % this.keep) * picked.length);
    this.controls?.set(this.control, (this.count % this.keep) * this.controlDim);
    this.last = picked;
    this.count += 1;
    this.motion += 1;
    this.inPart += 1;
    if (this.#partOver()) this.#nextPart();
    return true;
  }
}

/**
 * Embeddings (P, text_dim) and P limits (tokens, or null: until the model ends it; none given: all null) -> {parts:
 * P (text_dim) rows, limits}, checked.
 */
function actionsOf(emb, limits, textDim) {
  const P = emb.length / textDim;
  if (!Number.isInteger(P) || P < 1) {
    throw new RangeError(`expected (actions, ${textDim}) text embeddings, got ${emb.length} values`);
  }
  const parts = Array.from({ length: P }, (_, i) => emb.slice(i * textDim, (i + 1) * textDim));
  const given = limits?.length ? limits.map((n) => n ?? null) : parts.map(() => null);
  if (given.length !== P) throw new RangeError(`${P} actions but ${given.length} limits`);
  if (!given.every((n) => n === null || (Number.isInteger(n) && n >= 1))) {
    throw new RangeError(`an action's limit is a number of tokens (an int >= 1) or null, got ${shown(limits)}`);
  }
  return { parts, limits: given };
}

/**
 * A batch of endless streams, each stepped with its own calls (their contexts rebuild at different steps):
 * `step()` gives every stream its next token. textEmb (B, text_dim) and seeds (BigInt): one per stream; spec:
 * the manifest's `streaming` section.
 */
export class EndlessLoop {
  constructor(backend, textEmb, sampling, seeds, spec) {
    this.backend = backend;
    this.policy = new StepPolicy(sampling, backend.dims);
    const controlDim = backend.control ? backend.control.dim : 0;
    this.streams = seeds.map((seed, b) => new StreamContext(this.policy, this.#row(textEmb, b, seeds.length), seed, spec,
      controlDim));
    this.past = seeds.map(() => null);
    this.running = null;    // while a step runs: the index of the token after it
    this.deferred = null;   // a prompt switch asked for while a step runs, made when it ends
  }

  /** Tokens picked so far by each stream. */
  get count() { return this.streams[0].count; }

  /** Motions ended by END and started again, over all streams. */
  get restarts() { return this.streams.reduce((n, s) => n + s.restarts, 0); }

  /**
   * (B, text_dim) embeddings to follow from the next token on -> that token's index. Asked for while a step runs
   * (an await away), the switch is made when the step ends: the step was planned under the old prompt, and an END
   * it picks is picked again at once, so the new prompt must not reach it halfway (Python: EndlessLoop's lock).
   */
  setPrompt(textEmb) {
    const rows = this.streams.map((_, b) => this.#row(textEmb, b, this.streams.length));
    const make = () => this.streams.forEach((stream, b) => stream.condition(rows[b]));
    if (this.running === null) make();
    else this.deferred = make;   // a later switch replaces it: only the last would show
    return this.running ?? this.count;
  }

  /**
   * A one-stream loop's stream plays the actions of embeddings (P, text_dim) in order from the next token on, action
   * i for limits[i] tokens or (null) until the model ends it (StreamContext.condition); -> that token's index. Asked
   * for while a step runs, it is made when the step ends, as setPrompt.
   */
  setActions(textEmb, limits) {
    if (this.streams.length !== 1) {
      throw new RangeError(`setActions() steers a loop of one stream, this one has ${this.streams.length}`);
    }
    const emb = textEmb.slice(), given = limits && [...limits];
    actionsOf(emb, given, this.backend.dims.textDim);   // refused now, not when the step ends
    const make = () => this.streams[0].condition(emb, given);
    if (this.running === null) make();
    else this.deferred = make;
    return this.running ?? this.count;
  }

  #row(textEmb, b, batch) {
    const E = this.backend.dims.textDim;
    if (textEmb.length !== batch * E) throw new RangeError(`expected (${batch}, ${E}) text embeddings, got ${textEmb.length} values`);
    return textEmb.slice(b * E, (b + 1) * E);
  }

  /** -> the next tokens (B, L) of every stream. */
  async step() {
    const L = this.backend.dims.numLevels, picked = new Int32Array(this.streams.length * L);
    this.running = this.count + 1;
    try {
      for (let b = 0; b < this.streams.length; b++) picked.set(await this.#step(b), b * L);
    } finally {
      this.running = null;
      this.deferred?.();
      this.deferred = null;
    }
    return picked;
  }

  async #step(b) {
    const stream = this.streams[b], rows = this.policy.rows;
    for (let attempt = 0; attempt < 2; attempt++) {   // a pick of END is picked again from the restarted context
      const { tokens, controls, fresh, compact } = stream.plan();
      if (fresh) this.past[b] = this.backend.emptyPast(rows);
      if (compact) this.past[b] = this.backend.compact(this.past[b], ...stream.compaction);
      const out = await this.backend.step(stream.rowsEmb, this.policy.feed(tokens, 1), rows, this.past[b],
        controls && this.policy.feed(controls, 1));
      this.past[b] = out.past;
      const picked = this.policy.pick(out.logits, [stream.mayEnd], [stream.rng]);
      if (stream.accept(picked)) return picked;
    }
    throw new Error("unreachable: END is forbidden as a motion's first token");
  }
}
