// Tokenizes .hyb files with the grammar and fails on any character that no
// rule of the grammar scoped (only `source.hyb`): a construct the grammar
// does not know. Usage: node tests/coverage.js FILE...
"use strict";
const fs = require("fs");
const path = require("path");
const vsctm = require("vscode-textmate");
const oniguruma = require("vscode-oniguruma");

const wasm = fs.readFileSync(require.resolve("vscode-oniguruma/release/onig.wasm")).buffer;
const onigLib = oniguruma.loadWASM(wasm).then(() => ({
  createOnigScanner: (sources) => new oniguruma.OnigScanner(sources),
  createOnigString: (s) => new oniguruma.OnigString(s),
}));
const registry = new vsctm.Registry({
  onigLib,
  loadGrammar: async () =>
    vsctm.parseRawGrammar(
      fs.readFileSync(path.join(__dirname, "..", "syntaxes", "hyb.tmLanguage.json"), "utf8"),
      "hyb.tmLanguage.json",
    ),
});

(async () => {
  const grammar = await registry.loadGrammar("source.hyb");
  let problems = 0;
  for (const file of process.argv.slice(2)) {
    const lines = fs.readFileSync(file, "utf8").split(/\r?\n/);
    let stack = vsctm.INITIAL;
    lines.forEach((line, n) => {
      const r = grammar.tokenizeLine(line, stack);
      for (const tok of r.tokens) {
        const text = line.slice(tok.startIndex, tok.endIndex);
        if (tok.scopes.length === 1 && text.trim() !== "") {
          console.log(`${file}:${n + 1}:${tok.startIndex + 1}: unscoped \`${text.trim()}\``);
          problems++;
        }
      }
      stack = r.ruleStack;
    });
  }
  if (problems > 0) {
    console.log(`${problems} unscoped token(s)`);
    process.exit(1);
  }
  console.log(`${process.argv.length - 2} file(s): every token scoped`);
})();
