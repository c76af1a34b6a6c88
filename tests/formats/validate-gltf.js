// The Khronos glTF validator on each .gltf named on the command line, with
// its external buffers and images read from beside it. Prints each file's
// counts and its errors and warnings; exits 1 if any file has either.
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function validate(file) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    format: "gltf",
    externalResourceFunction: (uri) =>
      fs.promises.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri))).then((b) => new Uint8Array(b)),
  });
  const n = report.issues;
  console.log(
    `${file}: ${n.numErrors} errors, ${n.numWarnings} warnings, ${n.numInfos} infos, ${n.numHints} hints` +
      ` (validator ${report.validatorVersion})`
  );
  for (const m of n.messages.filter((m) => m.severity <= 1)) {
    console.log(`  ${m.severity === 0 ? "error" : "warning"} ${m.code} at ${m.pointer}: ${m.message}`);
  }
  return n.numErrors + n.numWarnings;
}

(async () => {
  let bad = 0;
  for (const f of process.argv.slice(2)) {
    bad += await validate(f);
  }
  process.exit(bad > 0 ? 1 : 0);
})().catch((e) => {
  console.error(`validation failed: ${e}`);
  process.exit(1);
});
