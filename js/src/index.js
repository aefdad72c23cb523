// mogo-runtime for JavaScript: text to 3D human motion from a mogo bundle on onnxruntime, giving the tokens
// the Python runtime gives for the same prompt, seed and sampling settings (docs/bundle.md is the contract).
//
//   import { MotionGenerator } from 'mogo-runtime';
//   const gen = await MotionGenerator.load('bundles/base', { variant: 'int8' });
//   const motion = await gen.generate('a person walks forward', { seconds: 4, seed: 1 });
//   motion.joints   // {data: Float32Array, dims: [frames, 22, 3]}, metres, y up
//
// A machine that only shows motion generated elsewhere decodes a token stream (wire/) with MotionClient, which
// opens the lookup and decoder graphs alone; ServerClient (serve/) gets that stream from a `mogo serve`.

export { MotionGenerator, FrameStream, MAX_SECONDS, checkTexts } from './generator.js';
export { Bundle } from './bundle/folder.js';
export { fileLoader, urlLoader, LoadError } from './bundle/io.js';
export { parseManifest } from './bundle/manifest.js';
export { SamplingConfig } from './bundle/sampling.js';
export { BundleError, WEIGHT_INT8 } from './bundle/sections.js';
export { MotionDecoder, OrtBackend, NonFiniteOutput } from './engine.js';
export { Tokenizer, TokenizerError } from './tokenizer.js';
export { PCG64 } from './pcg64.js';
export { StepPolicy, expandSeeds, makeRngs, sample } from './policy.js';
export { EndlessLoop, StreamContext } from './endless.js';
export { MAX_ACTIONS, MOST_SECONDS, planActions } from './plan.js';
export { FrameMaker, GenerationTask, checkChunk, collectTokens, decodeDue, decodeTokens, generateTokens } from './decoding.js';
export { SKELETONS } from './kinematics/skeleton.js';
export { recoverFromRic } from './kinematics/features.js';
export { FootLock, FrameJoints, RootIntegrator } from './kinematics/frames.js';
export { Steerable, Steering } from './control/steering.js';
export { FollowPath, GameRoot, Steer, WalkTo } from './control/targets.js';
export { controlDim, decode as decodeControl, encode as encodeControl } from './control/vector.js';
export { jointsToBvhText } from './outputs/bvh.js';
export { MAX_CHARACTERS, MotionClient } from './wire/client.js';
export { ConnectionClosed, ServerClient, ServerError } from './serve/client.js';
export { RecordReader, WireError, decoderId, encode as encodeRecord, helloFor, readMessage } from './wire/format.js';
// the whole token-stream format (records, constants), as Python's `from mogo_runtime.wire import format as wire`
export * as wire from './wire/format.js';
