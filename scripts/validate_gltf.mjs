// Validate a .glb/.gltf file with the Khronos glTF validator (npm package gltf-validator).
// Usage: node scripts/validate_gltf.mjs FILE [--json]
// Prints "errors N warnings N infos N hints N" and one line per error and warning; with --json the full
// report. Exit status: 0 when the file has no errors, 1 when it has errors, 2 on bad usage or an
// unreadable file.
import { readFile } from "node:fs/promises";
import { basename } from "node:path";
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
const args = process.argv.slice(2);
const json = args.includes("--json");
const files = args.filter((a) => a !== "--json");
if (files.length !== 1) {
  console.error("usage: node scripts/validate_gltf.mjs FILE [--json]");
  process.exit(2);
}
let validator;
try {
  validator = require("gltf-validator");
} catch {
  console.error("validate_gltf: the npm package gltf-validator is not installed (run 'npm ci' in the repository root)");
  process.exit(2);
}
let bytes;
try {
  bytes = new Uint8Array(await readFile(files[0]));
} catch (e) {
  console.error(`validate_gltf: ${files[0]}: cannot read (${e.code ?? e.message})`);
  process.exit(2);
}
let report;
try {
  report = await validator.validateBytes(bytes, { uri: basename(files[0]), maxIssues: 1000 });
} catch (e) {
  console.error(`validate_gltf: ${files[0]}: not glTF/GLB (${String(e).split("\n")[0]})`);
  process.exit(2);
}
const s = report.issues;
if (json) {
  console.log(JSON.stringify(report, null, 2));
} else {
  console.log(`errors ${s.numErrors} warnings ${s.numWarnings} infos ${s.numInfos} hints ${s.numHints}`);
  for (const m of s.messages) {
    if (m.severity <= 1) {
      console.log(`${m.severity === 0 ? "error" : "warning"} ${m.code} at ${m.pointer ?? "-"}: ${m.message}`);
    }
  }
}
process.exit(s.numErrors > 0 ? 1 : 0);
