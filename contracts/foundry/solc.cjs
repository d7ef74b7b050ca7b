#!/usr/bin/env node
// solc for forge, offline: forge calls `<solc> --version` and `<solc> --standard-json`
// (input on stdin). This answers both with solc-js 0.8.37 from node_modules (pinned in
// package.json), so forge never downloads a compiler. Imports forge did not put in the
// input resolve against the project root and node_modules.
'use strict';
const fs = require('node:fs');
const path = require('node:path');
const solc = require('solc');

const ROOT = path.resolve(__dirname, '..');
const args = process.argv.slice(2);

if (args.includes('--version')) {
  const v = solc.version().replace(/\.Emscripten\.clang$/, '');
  process.stdout.write(`solc, the solidity compiler commandline interface\nVersion: ${v}.Linux.g++\n`);
  process.exit(0);
}
if (!args.includes('--standard-json')) {
  process.stderr.write(`solc wrapper: only --version and --standard-json are supported, got ${args.join(' ')}\n`);
  process.exit(2);
}

function findImport(p) {
  for (const base of [ROOT, path.join(ROOT, 'node_modules')]) {
    const f = path.resolve(base, p);
    if (fs.existsSync(f)) return { contents: fs.readFileSync(f, 'utf8') };
  }
  return { error: `import not found: ${p}` };
}

const input = fs.readFileSync(0, 'utf8');
process.stdout.write(solc.compile(input, { import: findImport }));
