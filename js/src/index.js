// mogo-runtime for JavaScript: text to 3D human motion from a mogo bundle on onnxruntime, giving the tokens
// the Python runtime gives for the same prompt, seed and sampling settings (docs/bundle.md is the contract).
//
//   import { MotionGenerator } from 'mogo-runtime';
//   const gen = await MotionGenerator.load('bundles/base', { variant: 'int8' });
//   const motion = await gen.generate('a person walks forward', { seconds: 4, seed: 1 });
//   motion.joints   // {data: Float32Array, dims: [frames, 22, 3]}, metres, y up

export { MotionGenerator, FrameStream, MAX_SECONDS, checkTexts } from './generator.js';
export { SamplingConfig } from './sampling.js';
export { BundleError, parseManifest } from './manifest.js';
export { NonFiniteOutput } from './engine.js';
export { Bundle } from './bundle.js';
export { fileLoader, urlLoader, LoadError } from './io.js';
export { Tokenizer, TokenizerError } from './tokenizer.js';
export { PCG64 } from './pcg64.js';
export { OrtBackend } from './engine.js';
export { GenerationTask } from './task.js';
export { EndlessLoop, generateTokens, expandSeeds } from './loop.js';
export { FrameStreamer, decodeTokens } from './decode.js';
export { FootLock, recoverFromRic, RootIntegrator } from './features.js';
