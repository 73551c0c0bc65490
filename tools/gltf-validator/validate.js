#!/usr/bin/env node
// Validate glTF / GLB files with the Khronos glTF validator (npm package gltf-validator).
// Usage: node validate.js FILE [FILE ...]
// Prints one JSON array to stdout: [{file, numErrors, numWarnings, numInfos, messages}, ...].
// Exit code 0 when every file has 0 errors, 1 otherwise, 2 on a usage or read failure.
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function validateFile(file) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)));
      }),
  });
  const issues = report.issues;
  return {
    file,
    numErrors: issues.numErrors,
    numWarnings: issues.numWarnings,
    numInfos: issues.numInfos,
    messages: issues.messages,
  };
}

async function main() {
  const files = process.argv.slice(2);
  if (files.length === 0) {
    console.error("usage: node validate.js FILE [FILE ...]");
    process.exit(2);
  }
  const results = [];
  for (const file of files) {
    results.push(await validateFile(file));
  }
  console.log(JSON.stringify(results, null, 1));
  process.exit(results.every((r) => r.numErrors === 0) ? 0 : 1);
}

main().catch((err) => {
  console.error(String(err));
  process.exit(2);
});
