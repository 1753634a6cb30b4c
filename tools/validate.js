#!/usr/bin/env node
// Validate glTF / GLB files with the Khronos glTF-Validator (npm gltf-validator, pinned in package.json).
// Usage: node tools/validate.js FILE...  Prints one JSON report per file (one line each) and exits 1
// when any file has an error or a warning.
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function validate(file) {
  const full = path.resolve(file);
  const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(full)), {
    uri: path.basename(full),
    maxIssues: 100,
    externalResourceFunction: (uri) => new Promise((resolve, reject) => {
      fs.readFile(path.resolve(path.dirname(full), decodeURIComponent(uri)),
                  (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
    }),
  });
  const issues = report.issues;
  return {
    file: full, validatorVersion: report.validatorVersion, errors: issues.numErrors, warnings: issues.numWarnings,
    infos: issues.numInfos, hints: issues.numHints,
    messages: issues.messages.map((m) => ({ code: m.code, severity: m.severity, message: m.message, pointer: m.pointer })),
    extensionsUsed: (report.info && report.info.extensionsUsed) || [],
  };
}

(async () => {
  let bad = false;
  for (const file of process.argv.slice(2)) {
    const result = await validate(file);
    bad = bad || result.errors > 0 || result.warnings > 0;
    console.log(JSON.stringify(result));
  }
  process.exit(bad ? 1 : 0);
})().catch((e) => { console.error(String(e)); process.exit(2); });
