// Compile contracts/src/*.sol with solc-js (pinned in package.json) and write
// contracts/build/<Contract>.json = {contractName, abi, bytecode, deployedBytecode,
// sourceHash, compiler}. sourceHash is recomputed by backend/chain/artifacts.py to detect
// stale artifacts: sha256 over "<relpath>\0<sha256(content)>\n" for package.json,
// solc-settings.json and every src/**/*.sol, sorted by relpath.
import { createHash } from 'node:crypto';
import { readFileSync, writeFileSync, readdirSync, statSync, mkdirSync, existsSync } from 'node:fs';
import { join, relative, dirname, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { createRequire } from 'node:module';

const require = createRequire(import.meta.url);
const solc = require('solc');
const ROOT = dirname(fileURLToPath(import.meta.url));
const SRC = join(ROOT, 'src');
const OUT = join(ROOT, 'build');

function walk(dir) {
  return readdirSync(dir).flatMap((name) => {
    const p = join(dir, name);
    return statSync(p).isDirectory() ? walk(p) : p.endsWith('.sol') ? [p] : [];
  });
}

const sha256 = (buf) => createHash('sha256').update(buf).digest('hex');

export function sourceHash() {
  const files = [join(ROOT, 'package.json'), join(ROOT, 'solc-settings.json'), ...walk(SRC)];
  const rel = files.map((f) => relative(ROOT, f).split('\\').join('/')).sort();
  const h = createHash('sha256');
  for (const r of rel) h.update(`${r}\0${sha256(readFileSync(join(ROOT, r)))}\n`);
  return h.digest('hex');
}

function findImport(path) {
  for (const base of [join(ROOT, 'node_modules'), ROOT]) {
    const p = resolve(base, path);
    if (existsSync(p)) return { contents: readFileSync(p, 'utf8') };
  }
  return { error: `import not found: ${path}` };
}

const settings = JSON.parse(readFileSync(join(ROOT, 'solc-settings.json'), 'utf8'));
const sources = {};
for (const f of walk(SRC).sort()) {
  sources[relative(ROOT, f).split('\\').join('/')] = { content: readFileSync(f, 'utf8') };
}
const input = { language: 'Solidity', sources, settings };
const t0 = Date.now();
const output = JSON.parse(solc.compile(JSON.stringify(input), { import: findImport }));
const errors = (output.errors || []).filter((e) => e.severity === 'error');
for (const e of output.errors || []) {
  if (e.severity !== 'error' && !process.env.QUIET) console.error(e.formattedMessage);
}
if (errors.length) {
  for (const e of errors) console.error(e.formattedMessage);
  process.exit(1);
}
mkdirSync(OUT, { recursive: true });
const hash = sourceHash();
const version = solc.version();
let n = 0;
for (const [file, contracts] of Object.entries(output.contracts)) {
  if (!file.startsWith('src/')) continue;
  for (const [name, c] of Object.entries(contracts)) {
    const bytecode = c.evm.bytecode.object;
    if (!bytecode || c.abi.length === 0) continue; // interfaces, abstract contracts, libraries
    const art = {
      contractName: name,
      sourceName: file,
      abi: c.abi,
      bytecode: '0x' + bytecode,
      deployedBytecode: '0x' + c.evm.deployedBytecode.object,
      sourceHash: hash,
      compiler: version,
    };
    writeFileSync(join(OUT, `${name}.json`), JSON.stringify(art, null, 1) + '\n');
    n += 1;
    console.log(`${name}: ${bytecode.length / 2} bytes initcode, ` +
      `${c.evm.deployedBytecode.object.length / 2} bytes runtime`);
  }
}
console.log(`compiled ${n} contracts with solc ${version} in ${Date.now() - t0} ms; sourceHash ${hash}`);
