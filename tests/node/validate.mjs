// Validate a .glb with the Khronos glTF-Validator; prints its report as JSON.
//   node validate.mjs FILE.glb
import { readFileSync } from 'node:fs';
import validator from 'gltf-validator';

const file = process.argv[2];
const report = await validator.validateBytes(new Uint8Array(readFileSync(file)), {
  uri: file,
  maxIssues: 200,
  writeTimestamp: false,
});
process.stdout.write(JSON.stringify(report));
