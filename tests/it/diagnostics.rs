//! Malformed and ill-typed models: each case asserts the first diagnostic's
//! code, its `line:col` and its message exactly (and, for a few, the whole
//! rendering with the caret). Plus a property test: random and mutated
//! sources never make the front end panic.

use hybsim::diagnostics::{Diagnostic, render};

fn find(name: &str) -> &'static Case {
    CASES
        .iter()
        .find(|c| c.name == name)
        .expect("a case of the table")
}
use hybsim::lang::{self, Override};
use hybsim::source::SourceFile;

/// One malformed model and what `hybsim check` must say about it first.
struct Case {
    name: &'static str,
    src: &'static str,
    overrides: &'static [&'static str],
    code: &'static str,
    /// `line:col` of the primary label, or "" when the error is not in the
    /// file (overrides).
    at: &'static str,
    message: &'static str,
}

const fn case(
    name: &'static str,
    src: &'static str,
    code: &'static str,
    at: &'static str,
    message: &'static str,
) -> Case {
    Case {
        name,
        src,
        overrides: &[],
        code,
        at,
        message,
    }
}

fn diagnostics(src: &SourceFile, overrides: &[&str]) -> Vec<Diagnostic> {
    let mut ov: Vec<Override> = Vec::new();
    for s in overrides {
        match s.parse() {
            Ok(o) => ov.push(o),
            Err(d) => return vec![d],
        }
    }
    lang::check_only(src, &ov)
}

const CASES: &[Case] = &[
    // ---- habits of MATLAB and HyEQ users (help texts: `matlab_and_hyeq_habits_get_hybsims_spelling`) ----
    case(
        "a derivative written dot(x)",
        "model m\nstate x = 1, v = 0\nflow { dot(x) = v; dot(v) = -x }\n",
        "E0109",
        "3:8",
        "`dot(x)` is not how hybsim writes a derivative: write `x'`",
    ),
    case(
        "a derivative written der( x )",
        "model m\nstate x = 1\nflow { der( x ) = -x }\n",
        "E0109",
        "3:8",
        "`der(x)` is not how hybsim writes a derivative: write `x'`",
    ),
    case(
        "a derivative named x_dot",
        "model m\nstate x = 1, v = 0\nflow { x_dot = v; v_dot = -x }\n",
        "E0107",
        "3:8",
        "a flow equation gives a state's derivative, written with a prime: `x' = ...`",
    ),
    case(
        "MATLAB's sum of a vector",
        "model m\nstate x = [1; 2]\nflow { x' = -x }\noutput s = sum(x)\n",
        "E0109",
        "4:17",
        "`sum(x)` sums a vector in MATLAB; hybsim's `sum` runs over indices: `sum(k in 1..n: x[k])`",
    ),
    case(
        "MATLAB's sum of an expression",
        "model m\nstate x = [1; 2]\nflow { x' = -x }\noutput s = sum(2*x)\n",
        "E0109",
        "4:16",
        "`sum(v)` sums a vector in MATLAB; hybsim's `sum` runs over indices: `sum(k in 1..n: v[k])`",
    ),
    case(
        "MATLAB's end index",
        "model m\nstate x = [1; 2]\nflow { x' = -x }\noutput e = x[end]\n",
        "E0201",
        "4:14",
        "unknown name `end`",
    ),
    case(
        "two state declarations joined by a semicolon",
        "model m\nstate h = 1; v = 0\nflow { h' = v; v' = -1 }\n",
        "E0109",
        "2:12",
        "`;` ends the `state` declaration, so `v = ...` is not declared",
    ),
    case(
        "two state declarations without a comma",
        "model m\nstate x = 1 y = 2\nflow { x' = -y }\n",
        "E0109",
        "2:13",
        "`y = ...` follows the `state` declaration with no `,` before it",
    ),
    case(
        "two parameters without a comma, the first a call",
        "model m\nparam a = max(1, 2)  b2 = [1; 2]\nstate x = 1\nflow { x' = -a*x }\n",
        "E0109",
        "2:22",
        "`b2 = ...` follows the `param` declaration with no `,` before it",
    ),
    case(
        "HyEQ's tspan",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { tspan = [0, 10] }\n",
        "E0204",
        "4:7",
        "unknown setting `tspan`",
    ),
    case(
        "HyEQ's span as the horizon",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { J = [0, 20] }\n",
        "E0506",
        "4:11",
        "invalid `J`: the horizon is one number, the end of HyEQ's span [0, J]: write `J = ...` with that end alone",
    ),
    case(
        "odeset's RelTol",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { RelTol = 1e-8 }\n",
        "E0204",
        "4:7",
        "unknown setting `RelTol`",
    ),
    case(
        "MATLAB's function header",
        "model m\nfunction xdot = f(x)\nstate x = 1\nflow { x' = -x }\n",
        "E0109",
        "2:1",
        "hybsim has no `function`: a model declares its states and writes its flow, jumps and outputs directly",
    ),
    case(
        "resets separated by commas",
        "model m\nstate x = 1, v = 0\nflow { x' = v; v' = -1 }\njump r when x <= 0 { x+ = 0, v+ = -v }\n",
        "E0109",
        "4:28",
        "`,` does not separate resets: a newline or `;` does",
    ),
    case(
        "flow equations separated by commas",
        "model m\nstate x = 1, v = 0\nflow { x' = v, v' = -1 }\n",
        "E0109",
        "3:14",
        "`,` does not separate equations: a newline or `;` does",
    ),
    case(
        "a unit on a number",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { T = 10s }\n",
        "E0109",
        "4:11",
        "`10s`: a number has no unit in hybsim",
    ),
    case(
        "a unit on a number with an exponent",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { max_step = 1e-3s }\n",
        "E0109",
        "4:18",
        "`1e-3s`: a number has no unit in hybsim",
    ),
    case(
        "a unit on a number inside a flow equation",
        "model m\nstate x = 1\nflow { x' = -x/10s }\nsim { T = 1 }\n",
        "E0109",
        "3:16",
        "`10s`: a number has no unit in hybsim",
    ),
    case(
        "a unit on a number ending a line",
        "model m\nstate x = 1\nflow {\n    x' = -x/10s\n}\n",
        "E0109",
        "4:13",
        "`10s`: a number has no unit in hybsim",
    ),
    case(
        "a declared name glued to a number is no unit",
        "model m\nparam g = 9.81\nstate v = 0\nflow { v' = -g }\nsim { T = 2g }\n",
        "E0101",
        "5:12",
        "unexpected `g`; expected `'`, `[`, a setting `key = value` or an operator",
    ),
    case(
        "a vector compared in a flow set",
        "model m\nstate x = [1; 2; 3]\nflow { x' = -x } in x >= 0\n",
        "E0304",
        "3:21",
        "expected a condition such as `h >= 0`, found a 3×1 vector",
    ),
    case(
        "a vector compared for equality in a guard",
        "model m\nstate x = [1; 2]\njump when x == [0; 0] { x+ = [1; 1] }\n",
        "E0304",
        "3:11",
        "expected a condition such as `h >= 0`, found a 2×1 vector",
    ),
    case(
        "MATLAB's if block",
        "model m\nstate x = 1\nflow { x' = -x }\nif x > 0\n  x = 1\nend\n",
        "E0109",
        "4:1",
        "hybsim has no `if` statement: its `if` is an expression, `if c then a else b`",
    ),
    // ---- syntax (E01xx) ----
    case(
        "incomplete expression",
        "model m\nparam a = 1 +\nstate x = 0\n",
        "E0101",
        "3:1",
        "unexpected `state`; expected an expression",
    ),
    case(
        "unclosed matrix",
        "model m\nparam A = [1, 2; 3, 4\nstate x = 0\n",
        "E0108",
        "3:1",
        "`[` not closed: expected `]` before `state`",
    ),
    case(
        "flow equation with a dot for its prime",
        "model m\nstate x = 1\nflow { x. = -x }\n",
        "E0101",
        "3:9",
        "unexpected `.`; expected `'` (`x' = …`) or `[`",
    ),
    case(
        "a period that is not finite",
        "model m\nstate x = 1\njump r every inf { x+ = 0 }\n",
        "E0304",
        "3:14",
        "expected a finite, positive period, found inf",
    ),
    case(
        "a state family over the limit names its total",
        "model m\nfor i in 1..1000 { for k in 1..1e3 { state x[i, k] = [0; 0] } }\n",
        "E0307",
        "2:44",
        "2000000 scalar states: over the limit of 20000",
    ),
    case(
        "flow equation without a right-hand side",
        "model m\nstate x = 0\nflow { x' = }\n",
        "E0101",
        "3:13",
        "unexpected `}`; expected an expression",
    ),
    case(
        "MATLAB's space-separated matrix",
        "model m\nparam A = [0 1; -1 0]\n",
        "E0109",
        "2:14",
        "matrix entries are separated by `,` (rows by `;`), not by spaces",
    ),
    case(
        "MATLAB's sign-separated matrix entry",
        "model m\nparam b = [0 -1]\n",
        "E0109",
        "2:14",
        "ambiguous `-` inside `[ ]`: MATLAB reads `0 -1` as two entries, hybsim as a difference",
    ),
    // Operands side by side (a product written as in mathematics): the
    // parse stopped after them (at the `}`, "expected `[`") or at the second.
    case(
        "juxtaposed operands in a flow",
        "model m\nparam k = 2\nstate x = 1\nflow { x' = -k x }\n",
        "E0109",
        "4:16",
        "an operator is missing between `k` and `x`: hybsim does not multiply by juxtaposition",
    ),
    case(
        "juxtaposed operands in a guard",
        "model m\nstate x = 1, y = 0\nflow { x' = -1 }\njump r when x <= 2 y { y+ = 1 }\n",
        "E0109",
        "4:20",
        "an operator is missing between `2` and `y`: hybsim does not multiply by juxtaposition",
    ),
    case(
        "several juxtaposed operands",
        "model m\nstate x = 1\nflow { x' = sin(2 pi t) }\n",
        "E0109",
        "3:19",
        "an operator is missing between `2` and `pi`: hybsim does not multiply by juxtaposition",
    ),
    case(
        "juxtaposed operands in a parameter",
        "model m\nparam w = 2 pi, a = 1\n",
        "E0109",
        "2:13",
        "an operator is missing between `2` and `pi`: hybsim does not multiply by juxtaposition",
    ),
    case(
        "MATLAB's elseif",
        "model m\nparam p = if 1 > 2 then 1 elseif 1 > 0 then 2 else 3\n",
        "E0109",
        "2:27",
        "`elseif` is MATLAB's (and Julia's) spelling; hybsim writes `else if`",
    ),
    // Equations copied from a PDF bring typographic characters: each is
    // named with hybsim's ASCII spelling (the column counts characters).
    case(
        "typographic minus",
        "model m\nstate x = 1\nflow { x' = −x }\n",
        "E0109",
        "3:13",
        "`−` (U+2212) is a typographic character; hybsim writes `-`",
    ),
    case(
        "typographic prime",
        "model m\nstate x = 1\nflow { x′ = -x }\n",
        "E0109",
        "3:9",
        "`′` (U+2032) is a typographic character; hybsim writes `'`",
    ),
    case(
        "typographic comparison",
        "model m\nstate x = 1\nflow { x' = -x } in x ≥ 0\n",
        "E0109",
        "3:23",
        "`≥` (U+2265) is a typographic character; hybsim writes `>=`",
    ),
    case(
        "no-break space",
        "model m\nstate x = 1\nflow {\u{a0}x' = -x }\n",
        "E0109",
        "3:7",
        "the space character U+00A0 is a typographic character; hybsim writes an ordinary space",
    ),
    // "unexpected `=`; expected an expression" at the second `=`.
    case(
        "a flow equation written with `==`",
        "model m\nstate x = 1\nflow { x' == -x }\n",
        "E0109",
        "3:11",
        "`==` is a comparison; an equation is written with one `=`",
    ),
    case(
        "a reset written with `==`",
        "model m\nstate x = 1\nflow { x' = -x }\njump r when x <= 0.5 { x+ == 1 }\n",
        "E0109",
        "4:27",
        "`==` is a comparison; an equation is written with one `=`",
    ),
    // Names as a paper writes them: "unexpected `θ`; expected a name".
    case(
        "a Greek letter as a name",
        "model m\nstate θ = 1, ω = 0\nflow { θ' = ω; ω' = -θ }\n",
        "E0109",
        "2:7",
        "`θ` is not an ASCII name; hybsim writes `theta`",
    ),
    case(
        "a Greek letter with a subscript in an expression",
        "model m\nparam k = 2\nstate x = 1\nflow { x' = -ω₀ * x }\n",
        "E0109",
        "4:14",
        "`ω₀` is not an ASCII name; hybsim writes `omega0`",
    ),
    case(
        "a capital Greek letter and a subscript in a name",
        "model m\nparam Δt₁ = 0.1\n",
        "E0109",
        "2:7",
        "`Δt₁` is not an ASCII name; hybsim writes `Deltat1`",
    ),
    case(
        "a control character in the text",
        "model m\nstate x = \u{1b}[31m1\n",
        "E0101",
        "2:11",
        "unexpected control character U+001B; expected an expression",
    ),
    case(
        "an accented letter as a name",
        "model m\nstate été = 1\nflow { été' = -été }\n",
        "E0109",
        "2:7",
        "`été` is not an ASCII name",
    ),
    case(
        "a name begun in ASCII and continued in another script",
        "model m\nstate x_日本 = 1\nflow { x_日本' = -x_日本 }\n",
        "E0109",
        "2:7",
        "`x_日本` is not an ASCII name",
    ),
    case(
        "misspelt declaration keyword",
        "model m\nstat x = 1\nflow { x' = -x }\n",
        "E0101",
        "2:1",
        "`stat` does not start a declaration",
    ),
    case(
        "misspelt flow keyword",
        "model m\nstate x = 1; flwo { x' = -x }\n",
        "E0101",
        "2:14",
        "`flwo` does not start a declaration",
    ),
    // A first word far from every keyword was read as an instance's name,
    // and the error said only "expected `[`" after it.
    case(
        "another language's declaration",
        "model m\nconst g = 9.81\nstate x = 1\n",
        "E0101",
        "2:1",
        "`const` does not start a declaration",
    ),
    // A parameter or output without its value: the parser read on into the
    // next statement and said only "expected `[`" there.
    // MATLAB's and HyEQ's assignments, `g = 9.81` or `C = x >= 0`, were
    // read as an instance's name: "unexpected `9.81`; expected a name" at
    // the value, or "unexpected `=`; expected `[`" at the `=`.
    case(
        "a constant defined without `param`",
        "model m\ng = 9.81\nstate x = 1\n",
        "E0101",
        "2:1",
        "`g = …` is not a declaration: hybsim declares a name with a keyword",
    ),
    case(
        "a HyEQ flow set defined by assignment",
        "model m\nstate x = 1\nflow { x' = -x }\nC = x >= 0\n",
        "E0101",
        "4:1",
        "`C = …` is not a declaration: hybsim declares a name with a keyword",
    ),
    case(
        "a keyword glued to its name",
        "model m\nparamx = 1\n",
        "E0101",
        "2:1",
        "`paramx = …` is not a declaration: hybsim declares a name with a keyword",
    ),
    case(
        "a family member defined by assignment",
        "model m\nfor i in 1..2 { y[i] = i + 1 }\n",
        "E0101",
        "2:17",
        "`y[i] = …` is not a declaration: hybsim declares a name with a keyword",
    ),
    // `if` is an expression but not an operand: the message alone
    // ("expected an expression" at an `if`) contradicted itself.
    case(
        "an if expression as an operand",
        "model m\nparam d = [1; 2]\nstate x = 0, q = 1\nflow { x' = 1 }\njump r when x >= if q == 1 then d[1] else d[2] { x+ = 0 }\n",
        "E0101",
        "5:18",
        "unexpected `if`; expected an expression",
    ),
    case(
        "a parameter without its value",
        "model m\nparam k\nstate x = 1\nflow { x' = -k * x }\n",
        "E0101",
        "2:7",
        "`param k` has no value",
    ),
    case(
        "an output without its value, last in the file",
        "model m\nstate x = 1\nflow { x' = -x }\noutput y\n",
        "E0101",
        "4:8",
        "`output y` has no value",
    ),
    case(
        "a stray word at the end of the file",
        "model m\nstate x = 1\nflow { x' = -x }\nextra\n",
        "E0101",
        "4:1",
        "`extra` does not start a declaration",
    ),
    case(
        "a flow equation outside a flow block",
        "model m\nstate x = 1\nx' = -x\n",
        "E0101",
        "3:1",
        "a flow equation `x' = …` outside a flow block",
    ),
    case(
        "misspelt keyword where one is expected",
        "model m\nstate x = 1\njump r wen x <= 0 { x+ = 1 }\n",
        "E0101",
        "3:8",
        "unexpected `wen`; expected `[`, `every` or `when`",
    ),
    case(
        "keyword as a rule name",
        "model m\nstate x = 1\njump out when x <= 0 { x+ = 1 }\n",
        "E0101",
        "3:6",
        "`out` is a keyword, not a name",
    ),
    case(
        "jump without its block at the end of the file",
        "model m\nstate x = 1\njump r when x <= 0\n\n",
        "E0101",
        "3:19",
        "unexpected end of file; expected `'`, `[`, `{` or an operator",
    ),
    case(
        "property without its kind",
        "model m\nstate x = 1\nproperty p: x >= 0\n",
        "E0101",
        "3:13",
        "unexpected `x`; expected a property body (`always P`, `during flows P`, `at jumps P`, \
         `after E always P`, `eventually within T P`, `decreasing V during flows`, \
         `nonincreasing V at jumps`, `exponential V kappa K alpha A`)",
    ),
    case(
        "property scope without its word",
        "model m\nstate x = 1\nproperty p: during x >= 0\n",
        "E0101",
        "3:20",
        "unexpected `x`; expected `flows`",
    ),
    case(
        "power of a vector",
        "model m\nstate x = [1; 2]\nflow { x' = -x^2 }\n",
        "E0301",
        "3:14",
        "shape mismatch in `^ (scalars, or a square matrix to a constant integer power)`: 2×1 vector and scalar",
    ),
    case(
        "reset written without +",
        "model m\nstate x = 0\njump r when x >= 1 { x = 0 }\n",
        "E0104",
        "3:22",
        "a reset assigns the state after the jump: write `x+ = ...`",
    ),
    case(
        "reset of a member written without +",
        "model m\nstate x = [0; 0]\nevery 1 { x[2] = 1 }\n",
        "E0104",
        "3:11",
        "a reset assigns the state after the jump: write `x[2]+ = ...`",
    ),
    case(
        "number out of range",
        "model m\nparam a = 1e999\n",
        "E0103",
        "2:11",
        "number `1e999` is out of range",
    ),
    case(
        "MATLAB and",
        "model m\nstate x = 0\njump r when x >= 1 & x <= 2 { x+ = 0 }\n",
        "E0105",
        "3:20",
        "`&` is MATLAB's spelling; hybsim writes `&&`",
    ),
    case(
        "MATLAB or",
        "model m\nstate x = 0\njump r when x > 1 | x < 0 { x+ = 0 }\n",
        "E0105",
        "3:19",
        "`|` is MATLAB's spelling; hybsim writes `||`",
    ),
    case(
        "MATLAB not equal",
        "model m\nstate x = 0\njump r when x ~= 1 { x+ = 0 }\n",
        "E0105",
        "3:15",
        "`~=` is MATLAB's spelling; hybsim writes `!=`",
    ),
    case(
        "MATLAB not",
        "model m\nparam a = ~1\n",
        "E0105",
        "2:11",
        "`~` is MATLAB's spelling; hybsim writes `!`",
    ),
    // ---- names (E02xx) ----
    case(
        "MATLAB indexing",
        "model m\nstate x = [0; 0]\nflow { x' = [x(1); 0] }\n",
        "E0205",
        "3:14",
        "`x` is not a function; hybsim indexes with brackets: `x[...]`",
    ),
    case(
        "unknown name with a suggestion",
        "model m\nparam gravity = 9.81\nstate h = 1, v = 0\nflow { h' = v; v' = -gravty }\n",
        "E0201",
        "4:22",
        "unknown name `gravty`",
    ),
    case(
        "unknown rule of a property, blanks before the predicate",
        "model m\nstate x = 1\nflow { x' = -x }\njump r when x <= 0.5 { x+ = 1 }\nproperty p: at jumps rr   post(x) == 1\n",
        "E0201",
        "5:22",
        "unknown name `rr`",
    ),
    case(
        "unknown rule of a log block",
        "model m\nstate x = 1\nflow { x' = -x }\nfor i in 1..2 { jump f[i] when x <= 0.5 { x+ = 1 } }\nlog { rules = [g[3]] }\n",
        "E0201",
        "5:16",
        "unknown name `g[3]`",
    ),
    // A rule family's missing member is the family's error, as for states.
    case(
        "rule family member out of range in a log block, blanks before the bracket",
        "model m\nstate x = 1\nflow { x' = -x }\nfor i in 1..2 { jump f[i] when x <= 0.5 { x+ = 1 } }\nlog { rules = [f[3]   # none\n] }\n",
        "E0402",
        "5:16",
        "`f` has no member [3]",
    ),
    case(
        "rule family member out of range in count",
        "model m\nstate x = 1\nflow { x' = -x }\nfor i in 1..2 { jump f[i] when x <= 0.5 { x+ = 1 } }\nmetric c = count(f[0])\n",
        "E0402",
        "5:18",
        "`f` has no member [0]",
    ),
    case(
        "rule family member out of range in a property",
        "model m\nstate x = 1\nflow { x' = -x }\nfor i in 1..2 { jump f[i] when x <= 0.5 { x+ = 1 } }\nproperty p: at jumps f[5] post(x) == 1\n",
        "E0402",
        "5:22",
        "`f` has no member [5]",
    ),
    case(
        "unknown name in a reset",
        "model m\nstate x = 0\njump r when x >= 1 { x+ = zzz }\n",
        "E0201",
        "3:27",
        "unknown name `zzz`",
    ),
    case(
        "flow of an undeclared state",
        "model m\nstate x = 1\nflow { x' = 1; y' = 2 }\n",
        "E0201",
        "3:16",
        "unknown name `y`",
    ),
    case(
        "parameter used before its declaration",
        "model m\nparam a = b + 1\nparam b = 2\n",
        "E0201",
        "2:11",
        "unknown name `b`",
    ),
    case(
        "duplicate parameter",
        "model m\nparam a = 1\nparam a = 2\n",
        "E0202",
        "3:7",
        "`a` is declared twice",
    ),
    case(
        "state and parameter with one name",
        "model m\nparam x = 1\nstate x = 0\n",
        "E0202",
        "3:7",
        "`x` is declared twice",
    ),
    case(
        "duplicate rule",
        "model m\nstate x = 0\nflow { x' = 1 }\njump r when x >= 1 { x+ = 0 }\njump r when x >= 2 { x+ = 0 }\n",
        "E0202",
        "5:1",
        "`r` is declared twice",
    ),
    case(
        "duplicate family member",
        "model m\nfor i in 1..2 { state x[1] = 0 }\n",
        "E0202",
        "2:23",
        "`x[1]` is declared twice",
    ),
    case(
        "a sim setting given in two blocks",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { T = 10 }\nsim { T = 5 }\n",
        "E0202",
        "5:7",
        "`T` is set twice",
    ),
    case(
        "a setting given twice in two spellings",
        "model m\nstate x = 1\nflow { x' = -x }\nsim { T = 10; horizon_t = 5 }\n",
        "E0202",
        "4:15",
        "`horizon_t` is set twice",
    ),
    case(
        "two log blocks",
        "model m\nstate x = 1\nflow { x' = -x }\nlog { every = 2 }\nlog { dt = 0.1 }\n",
        "E0202",
        "5:1",
        "a second `log` block",
    ),
    case(
        "unknown function with a suggestion",
        "model m\nparam a = sqr(2)\n",
        "E0203",
        "2:11",
        "unknown function `sqr`",
    ),
    case(
        "MATLAB's range in a for loop",
        "model m\nparam N = 3\nfor i in 1:N { state x[i] = 0 }\n",
        "E0109",
        "3:11",
        "`a:b` is MATLAB's range; hybsim writes `a..b`",
    ),
    case(
        "MATLAB's range in a sum",
        "model m\nstate x = [1; 2; 3]\noutput s = sum(k in 1:3: x[k])\n",
        "E0109",
        "3:22",
        "`a:b` is MATLAB's range; hybsim writes `a..b`",
    ),
    case(
        "MATLAB's for loop",
        "model m\nparam N = 3\nflow { for i = 1:N { } }\n",
        "E0109",
        "3:14",
        "`for i = …` is MATLAB's loop; hybsim writes `for i in a..b`",
    ),
    case(
        "Python's range in a for loop",
        "model m\nparam N = 3\nfor i in range(N) { state x[i] = 0 }\n",
        "E0109",
        "3:10",
        "`range(N)` is Python's range; hybsim writes `1..N` (indices start at 1)",
    ),
    case(
        "a family declared with a range",
        "model m\nparam N = 3\nstate x[1..N] = 0\n",
        "E0109",
        "3:10",
        "`state x[1..N]` declares no family: its members are declared in a loop",
    ),
    case(
        "a slice written with a loop's range",
        "model m\nstate x = [1; 2; 3]\noutput s = x[1..2]\n",
        "E0109",
        "3:15",
        "`..` in an index: a slice is written `a:b`",
    ),
    case(
        "the base-10 logarithm",
        "model m\nparam a = log10(2)\n",
        "E0203",
        "2:11",
        "unknown function `log10`",
    ),
    case(
        "MATLAB's rand",
        "model m\nstate x = rand()\n",
        "E0203",
        "2:11",
        "unknown function `rand`",
    ),
    case(
        "MATLAB's exponential draw",
        "model m\nstate tau = exprnd(2)\n",
        "E0203",
        "2:13",
        "unknown function `exprnd`",
    ),
    case(
        "unknown reduction in a metric",
        "model m\nstate x = 1\nflow { x' = -x }\nmetric xT = last(x)\n",
        "E0203",
        "4:13",
        "unknown function `last`",
    ),
    case(
        "misspelt reduction in a metric",
        "model m\nstate x = 1\nflow { x' = -x }\nmetric m = integrl(x)\n",
        "E0203",
        "4:12",
        "unknown function `integrl`",
    ),
    case(
        "pre-jump value written pre(x)",
        "model m\nstate x = 1\nflow { x' = -x }\njump r when x <= 0.5 { x+ = 1 }\nproperty p: at jumps r post(x) > pre(x)\n",
        "E0203",
        "5:34",
        "unknown function `pre`",
    ),
    case(
        "unknown sim key with a suggestion",
        "model m\nstate x = 0\nsim { seeed = 3 }\n",
        "E0204",
        "3:7",
        "unknown setting `seeed`",
    ),
    // ---- shapes and kinds (E03xx) ----
    case(
        "matrix times vector of the wrong length",
        "model m\nparam A = [1, 2; 3, 4], b = [1; 2; 3]\nparam c = A * b\n",
        "E0301",
        "3:11",
        "shape mismatch in `*`: 2×2 matrix and 3×1 vector",
    ),
    case(
        "sum of vectors of different lengths",
        "model m\nstate x = [0; 0]\nflow { x' = x + [1; 2; 3] }\n",
        "E0301",
        "3:13",
        "shape mismatch in `+`: 2×1 vector and 3×1 vector",
    ),
    case(
        "flow equation of the wrong shape",
        "model m\nstate x = [0; 0]\nflow { x' = [1; 2; 3] }\n",
        "E0302",
        "3:13",
        "`x'` is a 2×1 vector but the right-hand side is a 3×1 vector",
    ),
    case(
        "reset of the wrong shape",
        "model m\nstate P = eye(2)\njump r when P[1, 1] >= 1 { P+ = [1; 2] }\n",
        "E0302",
        "3:33",
        "`P+` is a 2×2 matrix but the right-hand side is a 2×1 vector",
    ),
    case(
        "arity",
        "model m\nparam a = atan2(1)\n",
        "E0303",
        "2:11",
        "`atan2` takes 2 arguments but got 1",
    ),
    case(
        "inverse of a non-square matrix",
        "model m\nparam a = inv([1, 2])\n",
        "E0304",
        "2:15",
        "expected a square matrix, found a 1×2 matrix",
    ),
    case(
        "guard that is not a condition",
        "model m\nstate x = 0\njump r when x + 1 { x+ = 0 }\n",
        "E0304",
        "3:13",
        "expected a condition such as `h >= 0`, found a number",
    ),
    case(
        "period that depends on a state",
        "model m\nstate x = 1\nevery x { x+ = 0 }\n",
        "E0305",
        "3:7",
        "the period of `every` must be a constant",
    ),
    case(
        "overflowing matrix exponential in a parameter",
        "model m\nparam E = expm(1e308 * eye(2))\n",
        "E0306",
        "2:11",
        "cannot compute `expm`: the result overflows (an entry beyond the range of a 64-bit float)",
    ),
    case(
        "huge dimension",
        "model m\nparam N = 1e300\nstate x = zeros(N, 1)\n",
        "E0304",
        "3:17",
        "expected an integer of magnitude at most 1e15 for a dimension, found 1e300",
    ),
    case(
        "singular matrix in a parameter",
        "model m\nparam P = inv([1, 2; 2, 4])\n",
        "E0306",
        "2:11",
        "cannot compute `inv`: the matrix is singular",
    ),
    case(
        "model too large to compile",
        "model m\nparam A = ones(900, 900)\nparam B = A * A * A\n",
        "E0307",
        "3:11",
        "the model is too large to compile (more than 50000000 scalar operations)",
    ),
    // ---- indices (E04xx) ----
    case(
        "index out of range",
        "model m\nstate x = [0; 0]\noutput y = x[3]\n",
        "E0401",
        "3:14",
        "index 3 is out of range 1..2",
    ),
    case(
        "family member out of range",
        "model m\nfor i in 1..3 { state x[i] = 0 }\noutput y = x[4]\n",
        "E0402",
        "3:12",
        "`x` has no member [4]",
    ),
    case(
        "family used without an index",
        "model m\nfor i in 1..3 { state x[i] = 0 }\noutput y = x\n",
        "E0403",
        "3:12",
        "`x` is a family; index it as `x[i]`",
    ),
    // ---- structure (E05xx) ----
    case(
        "assignment to a parameter",
        "model m\nparam g = 1\nstate x = 0\nflow { g' = 0 }\n",
        "E0501",
        "4:8",
        "`g` is a parameter, not a state; only states can be assigned",
    ),
    case(
        "reset twice in one rule",
        "model m\nstate x = 0, y = 0\njump r when x >= 1 { x+ = 0; y+ = 1; x+ = 2 }\n",
        "E0502",
        "3:38",
        "`x` is reset twice in rule `r`",
    ),
    case(
        "family reset twice through a loop",
        "model m\nfor i in 1..2 { state x[i] = 0 }\njump r when x[1] >= 1 { for i in 1..2 { x[1]+ = i } }\n",
        "E0502",
        "3:41",
        "`x[1]` is reset twice in rule `r`",
    ),
    case(
        "two rules of a together group reset one state",
        "model m\nstate x = 0, y = 0\ntogether {\n  jump a when x >= 1 { x+ = 0; y+ = 1 }\n  jump b when y >= 1 { y+ = 0 }\n}\n",
        "E0510",
        "5:24",
        "`y` is reset by rules `a` and `b` of one `together` group",
    ),
    case(
        "two flow equations",
        "model m\nstate x = 0\nflow { x' = 1; x' = 2 }\n",
        "E0503",
        "3:16",
        "`x` has two flow equations",
    ),
    case(
        "missing initial value",
        "model m\nstate x\nflow { x' = 1 }\n",
        "E0504",
        "2:7",
        "state `x` has no initial value",
    ),
    case(
        "random draw in a flow",
        "model m\nstate x = 0\nflow { x' = uniform(0, 1) }\n",
        "E0505",
        "3:13",
        "random draws are not allowed in a flow equation",
    ),
    case(
        "negative horizon",
        "model m\nstate x = 0\nsim { T = -1 }\n",
        "E0506",
        "3:11",
        "invalid `T`: -1 is out of range: the horizon T is a positive finite time",
    ),
    // Values as written, not as 300 digits (`{x}` printed `0.000…01`).
    case(
        "tiny jump horizon",
        "model m\nstate x = 0\nsim { J = 1e-300 }\n",
        "E0506",
        "3:11",
        "invalid `J`: 1e-300 is out of range: the horizon J is a whole number of jumps ≥ 0, or inf (no bound)",
    ),
    case(
        "huge Zeno window",
        "model m\nstate x = 0\nsim { zeno_window = 1e300 }\n",
        "E0506",
        "3:21",
        "invalid `zeno_window`: 1e300 is not a whole number in 2..=4294967295",
    ),
    case(
        "tiny jump budget",
        "model m\nstate x = 0\nsim { max_total_jumps = 1e-300 }\n",
        "E0506",
        "3:25",
        "invalid `max_total_jumps`: 1e-300 is not an integer ≥ 1",
    ),
    case(
        "if-expression as a jump condition",
        "model m\nstate x = 0\nflow { x' = 1 }\njump r when if x > 0 then 1 else 2   { x+ = 0 }\n",
        "E0304",
        "4:13",
        "expected a condition such as `h >= 0`, found a number",
    ),
    case(
        "empty uniform range",
        "model m\nstate x = 0\njump r when x <= 0 { x+ = uniform(1, 0) }\n",
        "E0304",
        "3:27",
        "expected finite bounds lo ≤ hi in uniform(lo, hi), found uniform(1, 0)",
    ),
    case(
        "negative standard deviation",
        "model m\nstate x = 0\njump r when x <= 0 { x+ = normal(0, -1) }\n",
        "E0304",
        "3:27",
        "expected a finite mean and a standard deviation ≥ 0 in normal(mean, std), found normal(0, -1)",
    ),
    case(
        "probability above one",
        "model m\nstate x = 0\njump r when x <= 0 { x+ = bernoulli(1.5) }\n",
        "E0304",
        "3:27",
        "expected a probability in [0, 1] in bernoulli(p), found bernoulli(1.5)",
    ),
    case(
        "number as an operand of &&",
        "model m\nstate x = 0\nflow { x' = 1 }\njump r when x > 0 && 1 { x+ = 0 }\n",
        "E0304",
        "4:22",
        "expected a condition such as `h >= 0` as operand of `&&`, found a number",
    ),
    case(
        "vector of numbers as an operand of ||",
        "model m\nstate x = [0; 0]\nflow { x' = [1; 1] }\njump r when x > 0 || x { x+ = [0; 0] }\n",
        "E0304",
        "4:22",
        "expected a condition such as `h >= 0` as operand of `||`, found a 2×1 vector of numbers",
    ),
    case(
        "number negated with !",
        "model m\nstate x = 0\nflow { x' = 1 } in !x\n",
        "E0304",
        "3:21",
        "expected a condition such as `h >= 0` as operand of `!`, found a number",
    ),
    case(
        "unknown solver",
        "model m\nstate x = 0\nsim { solver = rk5 }\n",
        "E0506",
        "3:16",
        "invalid `solver`: `rk5` is not a solver; write one of dopri5, dop853, radau5, bdf, auto, rk4, euler_maruyama (did you mean `rk4`?)",
    ),
    case(
        "white noise without a stochastic solver",
        "model m\nnoise w ~ wiener(1)\nstate x = 0\nflow { x' = -x + w }\nsim { solver = dopri5 }\n",
        "E0506",
        "5:16",
        "invalid `solver`: white noise needs `solver = euler_maruyama`",
    ),
    case(
        "white noise squared",
        "model m\nnoise w ~ wiener(1)\nstate x = 0\nflow { x' = -x + w^2 }\nsim { solver = euler_maruyama }\n",
        "E0509",
        "4:8",
        "white noise must enter `x'` linearly",
    ),
    case(
        "vector operand in a guard",
        "model m\nstate h = 1, x = [1; 0]\nflow { h' = -1 }\njump r when h <= 0 && x <= 0 { h+ = 1 }\n",
        "E0304",
        "4:23",
        "expected a condition such as `h >= 0`, found a 2×1 vector",
    ),
    case(
        "vector operand in a flow set",
        "model m\nstate h = 1, v = 0, x = [1; 0]\nflow { h' = v } in !(h >= 0 || x >= 0)\n",
        "E0304",
        "3:32",
        "expected a condition such as `h >= 0`, found a 2×1 vector",
    ),
    Case {
        name: "override of an unknown name",
        src: "model m\nparam lambda = 0.8\nstate x = 0\n",
        overrides: &["lamda=0.5"],
        code: "E0204",
        at: "1:1", // of `--set lamda`
        message: "unknown setting `lamda` in override `lamda=0.5`",
    },
    Case {
        name: "override with nan",
        src: "model m\nparam g = 1\nstate x = 0\n",
        overrides: &["g=nan"],
        code: "E0508",
        at: "1:3", // of `--set g=nan`
        message: "in override `g=nan`: unknown name `nan`",
    },
    Case {
        name: "override that is not an expression",
        src: "model m\nparam g = 1\nstate x = 0\n",
        overrides: &["g=[1,"],
        code: "E0508",
        at: "1:6", // of `--set g`
        message: "in override `g=[1,`: unexpected end of file; expected an expression",
    },
    Case {
        name: "override whose value names an unknown parameter",
        src: "model m\nparam g = 1\nstate x = g\nflow { x' = g }\n",
        overrides: &["g=foo"],
        code: "E0508",
        at: "1:3",
        message: "in override `g=foo`: unknown name `foo`",
    },
    Case {
        name: "override of the wrong shape",
        src: "model m\nparam g = 1\nparam v = [1; 2] + g\n",
        overrides: &["g=[1; 2; 3]"],
        code: "E0301",
        at: "3:11",
        message: "shape mismatch in `+`: 2×1 vector and 3×1 vector",
    },
];

#[test]
fn malformed_models_report_location_and_message() {
    assert!(CASES.len() >= 25);
    let mut failures = Vec::new();
    for c in CASES {
        let src = SourceFile::new("m.hyb", c.src);
        let diags = diagnostics(&src, c.overrides);
        let Some(d) = diags.first() else {
            failures.push(format!("{}: no diagnostic", c.name));
            continue;
        };
        let at = d
            .line_col(&src)
            .map(|lc| lc.to_string())
            .unwrap_or_default();
        if (d.code, at.as_str(), d.message.as_str()) != (c.code, c.at, c.message) {
            failures.push(format!(
                "{}:\n    expected {} {} {:?}\n    found    {} {} {:?}",
                c.name, c.code, c.at, c.message, d.code, at, d.message
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Suggestions for misspelt names (strsim over the declared names).
#[test]
fn unknown_names_come_with_the_closest_declared_name() {
    for (name, help) in [
        ("unknown name with a suggestion", "did you mean `gravity`?"),
        ("unknown function with a suggestion", "did you mean `sqrt`?"),
        ("unknown sim key with a suggestion", "did you mean `seed`?"),
        ("unknown reduction in a metric", "did you mean `final`?"),
        ("misspelt reduction in a metric", "did you mean `integral`?"),
        ("override of an unknown name", "did you mean `lambda`?"),
        (
            "override with nan",
            "there is no `nan` constant: write `0/0` for NaN (`inf` is a constant)",
        ),
        ("misspelt declaration keyword", "did you mean `state`?"),
        ("misspelt flow keyword", "did you mean `flow`?"),
        (
            "misspelt keyword where one is expected",
            "did you mean `when`?",
        ),
        ("keyword as a rule name", "choose another name than `out`"),
        (
            "pre-jump value written pre(x)",
            "there is no `pre`: a bare name is the value before the jump (`x`); `post(x)`, in a property `at jumps`, is the value after it",
        ),
    ] {
        let c = find(name);
        let d = diagnostics(&SourceFile::new("m.hyb", c.src), c.overrides);
        assert_eq!(d[0].help.as_deref(), Some(help), "{name}");
    }
}

/// What a user of MATLAB and the HyEQ Toolbox writes by habit gets hybsim's spelling in
/// the help (the cases above give the messages and places).
#[test]
fn matlab_and_hyeq_habits_get_hybsims_spelling() {
    for (name, help) in [
        (
            "a derivative written dot(x)",
            "a `flow` block holds equations `x' = f(x)`, the state's name with a prime",
        ),
        (
            "a derivative named x_dot",
            "if `x_dot` is the derivative of `x`, write `x' = ...`",
        ),
        (
            "MATLAB's sum of a vector",
            "write `sum(k in 1..length(x): x[k])` for the entries of a vector, or `ones(1, length(x))*x`",
        ),
        (
            "MATLAB's end index",
            "there is no `end` index: write the last index, `x[length(x)]` (`P[rows(P), :]`, `P[:, cols(P)]` for a matrix)",
        ),
        (
            "two state declarations joined by a semicolon",
            "declare several on one line with `,`: `state h = 1, v = ...` (or repeat the keyword: `; state v = ...`)",
        ),
        (
            "MATLAB's function header",
            "write the function's body as the model: `state x = ...`, `flow { x' = ... }` for `xdot = f(x)`, `jump when C { x+ = ... }` for a jump map, `output y = ...` for a value computed from the state",
        ),
        (
            "resets separated by commas",
            "put each of the block's resets on its own line, or end each with `;`: `{ x+ = 0; v+ = -v }`",
        ),
        (
            "a unit on a number",
            "write the number alone, in the model's units: `10` (a comment can name the unit: `# s`)",
        ),
        (
            "a vector compared in a flow set",
            "a condition is one true/false value: write `min(x) >= 0` for every component, `max(x) >= 0` for some component, or join the components' conditions with `&&`: `x[1] >= 0 && ...`",
        ),
        (
            "a vector compared for equality in a guard",
            "a condition is one true/false value: for every component equal, join the components' conditions with `&&`: `x[1] == c && x[2] == c && ...`",
        ),
        (
            "MATLAB's if block",
            "choose a value with `if c then a else b` (`x' = if x > 0 then -1 else 1`); change the state when a condition holds with a jump guarded by it, `jump when c { x+ = ... }`",
        ),
        (
            "MATLAB's range in a for loop",
            "a range is `a..b`, both ends included (`for i in 1..N`, `sum(k in 1..N: x[k])`), in steps of 1: for another step filter it, `for i in 1..N if mod(i, 2) == 0`",
        ),
        (
            "MATLAB's range in a sum",
            "a range is `a..b`, both ends included (`for i in 1..N`, `sum(k in 1..N: x[k])`), in steps of 1: for another step filter it, `for i in 1..N if mod(i, 2) == 0`",
        ),
        (
            "MATLAB's for loop",
            "a range is `a..b`, both ends included (`for i in 1..N`, `sum(k in 1..N: x[k])`), in steps of 1: for another step filter it, `for i in 1..N if mod(i, 2) == 0`",
        ),
        (
            "a family declared with a range",
            "write `for i in 1..N { state x[i] = … }` for a family (read as `x[i]`), or one vector, `state x = zeros(N, 1)` (read as `x[1]`, …)",
        ),
        (
            "a slice written with a loop's range",
            "`x[2:3]` is the entries 2 to 3, `x[:, 1]` a column; `a..b` is the range of a loop or a sum",
        ),
        // Not the nearest built-in (`log`, `round`, `exp`): another function.
        (
            "the base-10 logarithm",
            "`log` is the natural logarithm: the base-10 logarithm is `log(x)/log(10)`",
        ),
        (
            "MATLAB's rand",
            "MATLAB's `rand` is the draw `uniform(0, 1)` (in initial values and resets; `noise` for flows)",
        ),
        (
            "MATLAB's exponential draw",
            "a draw from the exponential distribution of mean m (rate 1/m) is `-m*log(uniform(0, 1))`; `exp(x)` is the exponential function",
        ),
        ("HyEQ's tspan", "did you mean `T`?"),
        ("odeset's RelTol", "did you mean `rtol`?"),
        (
            "a constant defined without `param`",
            "write `param g = …` for a constant, `state g = …` for a state and its initial value, or `output g = …` for a logged expression (a statement without a keyword is an instance of a subsystem, `g = Subsystem(…)`)",
        ),
        (
            "a HyEQ flow set defined by assignment",
            "write `param C = …` for a constant, `state C = …` for a state and its initial value, or `output C = …` for a logged expression (a statement without a keyword is an instance of a subsystem, `C = Subsystem(…)`); HyEQ's flow set C is written after the flow block, `flow { … } in x >= 0`",
        ),
        (
            "a keyword glued to its name",
            "if `paramx` is `param x`, separate the words: `param x = …`; else write `param paramx = …` for a constant, `state paramx = …` for a state and its initial value, or `output paramx = …` for a logged expression (a statement without a keyword is an instance of a subsystem, `paramx = Subsystem(…)`)",
        ),
        (
            "an if expression as an operand",
            "`if c then a else b` extends as far as it can, so it starts an expression, not an operand: write the operand in parentheses, `x >= (if c then a else b)`",
        ),
    ] {
        let c = find(name);
        let d = diagnostics(&SourceFile::new("m.hyb", c.src), c.overrides);
        assert_eq!(d[0].help.as_deref(), Some(help), "{name}");
    }
    // What the helps propose compiles, and `xdot` names `x` too.
    let fixed = "model m\nstate x = [1; 2], h = 1, v = 0\n\
                 flow { x' = -x; h' = v; v' = -1 } in min(x) >= 0 || max(x) >= 0 || x[1] >= 0\n\
                 output s = sum(k in 1..length(x): x[k]), s2 = ones(1, length(x))*x, e = x[length(x)]\n\
                 param g = 9.81\njump r when h >= (if g > 1 then 2 else 3) { h+ = 0 }\n\
                 param N = 3, l10 = log(2)/log(10)\nfor i in 1..N if mod(i, 2) == 0 { state y[i] = 0 }\n\
                 state z = zeros(N, 1)\noutput zs = x[1:2]\n\
                 state u = uniform(0, 1), tau = -2*log(uniform(0, 1))\n\
                 sim { T = 10; J = 20; rtol = 1e-8; priority = jumps }\n";
    let src = SourceFile::new("m.hyb", fixed);
    let d = diagnostics(&src, &[]);
    assert!(d.is_empty(), "{}", render(&d, &src, false));
    let src = SourceFile::new("m.hyb", "model m\nstate x = 1\nflow { xdot = -x }\n");
    let d = diagnostics(&src, &[]);
    assert_eq!(
        d[0].help.as_deref(),
        Some("if `xdot` is the derivative of `x`, write `x' = ...`")
    );
    // HyEQ's `rule` is the priority, on the command line as in the `sim` block.
    let src = SourceFile::new("m.hyb", "model m\nstate x = 1\nflow { x' = -x }\n");
    for d in [
        diagnostics(
            &SourceFile::new(
                "m.hyb",
                "model m\nstate x = 1\nflow { x' = -x }\nsim { rule = 1 }\n",
            ),
            &[],
        ),
        diagnostics(&src, &["rule=1"]),
        diagnostics(&src, &["TSPAN=10"]),
    ] {
        assert_eq!(d[0].code, "E0204");
        assert!(
            matches!(
                d[0].help.as_deref(),
                Some("did you mean `priority`?" | "did you mean `T`?")
            ),
            "{:?}",
            d[0].help
        );
    }
}

/// The values of word-valued settings as a HyEQ or MATLAB user writes them: `priority = flow`
/// or `jump` (keywords: the parse stopped with "expected an expression"), HyEQ's `rule`
/// numbers after the rename to `priority`, a misspelt word, MATLAB's `ode45` (each was only
/// "write one of …").
#[test]
fn word_settings_name_their_words_and_the_closest() {
    let cases: &[(&str, &str, &str, &str)] = &[
        (
            "priority = flow",
            "E0101",
            "`flow` is a keyword, not a value of `priority`",
            "did you mean `flows`? `priority` is one of jumps, flows, random",
        ),
        (
            "priority = jump",
            "E0101",
            "`jump` is a keyword, not a value of `priority`",
            "did you mean `jumps`? `priority` is one of jumps, flows, random",
        ),
        (
            "exact_affine = in",
            "E0101",
            "`in` is a keyword, not a value of `exact_affine`",
            "`exact_affine` is one of auto, on, off",
        ),
        (
            "priority = 2",
            "E0506",
            "invalid `priority`: write one of jumps, flows, random (HyEQ's `rule = 1` is `jumps`, 2 is `flows`, 3 is `random`)",
            "",
        ),
        (
            "priority = jmps",
            "E0506",
            "invalid `priority`: write one of jumps, flows, random (did you mean `jumps`?)",
            "",
        ),
        (
            "solver = ode45",
            "E0506",
            "invalid `solver`: `ode45` is not a solver; write one of dopri5, dop853, radau5, bdf, auto, rk4, euler_maruyama (MATLAB's `ode45` is `dopri5` here)",
            "",
        ),
        (
            "jump_choice = frist",
            "E0506",
            "invalid `jump_choice`: write one of first, random (did you mean `first`?)",
            "",
        ),
    ];
    for (setting, code, message, help) in cases {
        let text =
            format!("model m\nstate x = 1\nflow {{ x' = -x }}\nsim {{ T = 1; {setting} }}\n");
        let d = diagnostics(&SourceFile::new("m.hyb", text), &[]);
        assert_eq!(d.len(), 1, "{setting}: {d:?}");
        assert_eq!(d[0].code, *code, "{setting}");
        assert_eq!(d[0].message, *message, "{setting}");
        let value = 50 + setting.find('=').unwrap() + 2;
        assert_eq!(d[0].labels[0].span.start, value, "{setting}: at the value");
        if !help.is_empty() {
            assert_eq!(d[0].help.as_deref(), Some(*help), "{setting}");
        }
    }
    // On the command line too.
    let src = SourceFile::new("m.hyb", "model m\nstate x = 1\nflow { x' = -x }\n");
    for o in ["priority=flow", "sim.priority=flow"] {
        let d = diagnostics(&src, &[o]);
        assert_eq!(d[0].code, "E0508", "{o}");
        assert_eq!(
            d[0].help.as_deref(),
            Some("did you mean `flows`? `priority` is one of jumps, flows, random"),
            "{o}"
        );
    }
}

/// Conditions are what `&&`, `||` and `!` take: comparisons, `true`/`false`, parameters and
/// outputs set to one, members of a matrix of them (a number there is E0304, above).
#[test]
fn logical_operators_take_every_kind_of_condition() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam on = true, ok = [true; false], both = [true, false; false, true]\n\
         state x = 1\noutput inside = x > 0\nflow { x' = -1 } in !(x < -5) || on\n\
         jump r when (ok[1] && inside) || (both[2, 2] && !(x > 0)) { x+ = 1 }\n",
    );
    let d = diagnostics(&src, &[]);
    assert!(d.is_empty(), "{}", render(&d, &src, false));
}

/// The whole rendering: file:line:col, the line, the caret and its label,
/// the second place involved, and the help.
#[test]
fn renderings_show_the_line_and_the_caret() {
    let mut got = Vec::new();
    for (name, expected) in RENDERED {
        let c = find(name);
        let src = SourceFile::new("m.hyb", c.src);
        let text = render(&diagnostics(&src, c.overrides), &src, false);
        got.push((text, expected));
    }
    for (text, expected) in got {
        assert_eq!(text, *expected);
    }
}

const RENDERED: &[(&str, &str)] = &[
    (
        "unknown name with a suggestion",
        "error[E0201]: unknown name `gravty`\n  ┌─ m.hyb:4:22\n  │\n4 │ flow { h' = v; v' = -gravty }\n  │                      ^^^^^^ not found\n  │\n  = help: did you mean `gravity`?\n\n",
    ),
    (
        "flow of an undeclared state",
        "error[E0201]: unknown name `y`\n  ┌─ m.hyb:3:16\n  │\n3 │ flow { x' = 1; y' = 2 }\n  │                ^ not declared\n  │\n  = help: only states are assigned: declare it first, e.g. `state y = 0`\n\n",
    ),
    (
        "matrix times vector of the wrong length",
        "error[E0301]: shape mismatch in `*`: 2×2 matrix and 3×1 vector\n  ┌─ m.hyb:3:11\n  │\n3 │ param c = A * b\n  │           ^^^^^ 2×2 matrix and 3×1 vector\n  │\n  = help: check the dimensions; use `'` to transpose\n\n",
    ),
    (
        "power of a vector",
        "error[E0301]: shape mismatch in `^ (scalars, or a square matrix to a constant integer power)`: 2×1 vector and scalar\n  ┌─ m.hyb:3:14\n  │\n3 │ flow { x' = -x^2 }\n  │              ^^^ 2×1 vector and scalar\n  │\n  = help: `^` is not elementwise: write `x .* x` for the squares of a vector's entries\n\n",
    ),
    (
        "MATLAB's space-separated matrix",
        "error[E0109]: matrix entries are separated by `,` (rows by `;`), not by spaces\n  ┌─ m.hyb:2:14\n  │\n2 │ param A = [0 1; -1 0]\n  │              ^ `,` expected before this entry\n  │\n  = help: write `[0, 1; -1, 0]` for MATLAB's `[0 1; -1 0]`\n\n",
    ),
    (
        "reset twice in one rule",
        "error[E0502]: `x` is reset twice in rule `r`\n  ┌─ m.hyb:3:38\n  │\n3 │ jump r when x >= 1 { x+ = 0; y+ = 1; x+ = 2 }\n  │                      -               ^ reset again here\n  │                      │                \n  │                      first reset here\n  │\n  = help: keep one reset per state in each rule\n\n",
    ),
    (
        // The caret ends with the else branch, not at the spaces after it.
        "if-expression as a jump condition",
        "error[E0304]: expected a condition such as `h >= 0`, found a number\n  ┌─ m.hyb:4:13\n  │\n4 │ jump r when if x > 0 then 1 else 2   { x+ = 0 }\n  │             ^^^^^^^^^^^^^^^^^^^^^^ expected a condition such as `h >= 0`\n\n",
    ),
    (
        // The caret covers the name, not the blanks pest skips after it.
        "unknown rule of a property, blanks before the predicate",
        "error[E0201]: unknown name `rr`\n  ┌─ m.hyb:5:22\n  │\n5 │ property p: at jumps rr   post(x) == 1\n  │                      ^^ not found\n  │\n  = help: did you mean `r`?\n\n",
    ),
    (
        "rule family member out of range in a log block, blanks before the bracket",
        "error[E0402]: `f` has no member [3]\n  ┌─ m.hyb:5:16\n  │\n5 │ log { rules = [f[3]   # none\n  │                ^^^^ no such member\n  │\n  = its members are [1], [2]\n\n",
    ),
    (
        "family member out of range",
        "error[E0402]: `x` has no member [4]\n  ┌─ m.hyb:3:12\n  │\n3 │ output y = x[4]\n  │            ^^^^ no such member\n  │\n  = its members are [1], [2], [3]\n\n",
    ),
];

// ------------------------------------------------------------ no panics --

mod no_panic {
    use proptest::prelude::*;
    use proptest::test_runner::Config;

    use hybsim::diagnostics::render;
    use hybsim::lang;
    use hybsim::source::SourceFile;

    /// Every model of `models/`.
    fn models() -> Vec<String> {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/models");
        let mut paths: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
            .collect();
        paths.sort();
        paths
            .iter()
            .map(|p| std::fs::read_to_string(p).unwrap())
            .collect()
    }

    /// Pieces of the language a mutation inserts.
    const TOKENS: &[&str] = &[
        "model",
        "param",
        "state",
        "flow",
        "jump",
        "when",
        "every",
        "noise",
        "output",
        "sim",
        "graph",
        "for",
        "in",
        "if",
        "then",
        "else",
        "sum",
        "out",
        "edges",
        "{",
        "}",
        "(",
        ")",
        "[",
        "]",
        ",",
        ";",
        ":",
        "..",
        "'",
        "+",
        "-",
        "*",
        "/",
        ".*",
        "./",
        "^",
        "=",
        "~",
        "<=",
        ">=",
        "==",
        "!=",
        "&&",
        "||",
        "!",
        "x",
        "i",
        "N",
        "0",
        "1",
        "-1",
        "1e308",
        "1e999",
        "0.5",
        "1000000",
        "x[0]",
        "x[1]",
        "x[i]",
        "[1, 2; 3, 4]",
        "eye(3)",
        "inv(",
        "expm(",
        "kron(",
        "wiener(2)",
        "uniform(0, 1)",
        "sum(i in 1..3: ",
        "for i in 1..3 {",
        "\n",
        "#",
        "\"",
        "é",
        "∞",
    ];

    #[derive(Debug, Clone)]
    enum Mutation {
        Delete(f64, usize),
        Insert(f64, usize),
        Replace(f64, char),
        Duplicate(f64, usize),
    }

    fn mutation() -> impl Strategy<Value = Mutation> {
        prop_oneof![
            (0.0..1.0, 1..40usize).prop_map(|(p, n)| Mutation::Delete(p, n)),
            (0.0..1.0, 0..TOKENS.len()).prop_map(|(p, k)| Mutation::Insert(p, k)),
            (0.0..1.0, any::<char>()).prop_map(|(p, c)| Mutation::Replace(p, c)),
            (0.0..1.0, 1..40usize).prop_map(|(p, n)| Mutation::Duplicate(p, n)),
        ]
    }

    fn apply(text: &str, muts: &[Mutation]) -> String {
        let mut s: Vec<char> = text.chars().collect();
        for m in muts {
            let at = |p: f64, len: usize| ((p * len as f64) as usize).min(len);
            match *m {
                Mutation::Delete(p, n) => {
                    let i = at(p, s.len());
                    let j = (i + n).min(s.len());
                    s.drain(i..j);
                }
                Mutation::Insert(p, k) => {
                    let i = at(p, s.len());
                    let tok: Vec<char> = format!(" {} ", TOKENS[k]).chars().collect();
                    s.splice(i..i, tok);
                }
                Mutation::Replace(p, c) => {
                    if !s.is_empty() {
                        let i = at(p, s.len() - 1);
                        s[i] = c;
                    }
                }
                Mutation::Duplicate(p, n) => {
                    let i = at(p, s.len());
                    let j = (i + n).min(s.len());
                    let piece: Vec<char> = s[i..j].to_vec();
                    s.splice(j..j, piece);
                }
            }
        }
        s.into_iter().collect()
    }

    /// Parses, checks, compiles and renders the diagnostics: none may panic.
    fn front_end(text: &str) {
        let src = SourceFile::new("fuzz.hyb", text);
        let diags = lang::check_only(&src, &[]);
        let _ = render(&diags, &src, false);
        if let Err(diags) = lang::compile(&src, &[]) {
            assert!(!diags.is_empty());
            let _ = render(&diags, &src, true);
        }
    }

    proptest! {
        #![proptest_config(Config { cases: 300, failure_persistence: None, ..Config::default() })]

        #[test]
        fn mutated_models_never_panic(
            k in 0..64usize,
            muts in proptest::collection::vec(mutation(), 1..6),
        ) {
            let models = models();
            let text = apply(&models[k % models.len()], &muts);
            front_end(&text);
        }
    }

    proptest! {
        #![proptest_config(Config { cases: 100, failure_persistence: None, ..Config::default() })]

        #[test]
        fn random_sources_never_panic(
            text in "\\PC{0,200}",
            toks in proptest::collection::vec(0..TOKENS.len(), 0..60),
        ) {
            front_end(&text);
            let soup: Vec<&str> = toks.iter().map(|&k| TOKENS[k]).collect();
            front_end(&format!("model m\n{}", soup.join(" ")));
        }
    }
}

/// A `for` header is evaluated in each pass over the model; an error in it
/// (a range bound that is not an integer, in the file or from `--set`) is
/// reported once, not once per pass.
#[test]
fn an_error_in_a_loop_header_is_reported_once() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam N = 3\nstate h = 1\nfor i in 1..2.5 { state z[i] = 0 }\n\
         for i in 1..N { state y[i] = 0 }\nflow { h' = -h }\n",
    );
    let diags = diagnostics(&src, &[]);
    let at: Vec<_> = diags
        .iter()
        .map(|d| (d.code, d.line_col(&src).map(|lc| lc.to_string())))
        .collect();
    assert_eq!(at, [("E0304", Some("4:13".to_string()))], "{diags:#?}");
    let diags = diagnostics(&src, &["N=2.5"]);
    let at: Vec<_> = diags
        .iter()
        .map(|d| (d.code, d.line_col(&src).map(|lc| lc.to_string())))
        .collect();
    assert_eq!(
        at,
        [
            ("E0304", Some("4:13".to_string())),
            ("E0304", Some("5:13".to_string()))
        ],
        "{diags:#?}"
    );
}

/// The hint of an unknown `--set` name is a name `--set` accepts: never a
/// family, a member of one or an instance family's parameter, which it
/// refuses (`fam[2].x0` once suggested `fam.x0`, which suggested `fam.x`,
/// which suggested `fam.xa`, all refused). A name that designates a family
/// says so.
#[test]
fn override_hints_name_only_what_set_accepts() {
    let text = "model m\nparam lambda = 0.8, N = 3\n\
        subsystem Room(a = 0.5, xa = 5, x0 = 20) { state x = x0; flow { x' = -a * (x - xa) } }\n\
        r1 = Room()\nfor i in 1..N { fam[i] = Room(x0 = 18 + i) }\n\
        for i in 1..N { state z[i] = i; param p[i] = 2 * i }\n\
        flow { for i in 1..N { z[i]' = -p[i] * z[i] } }\n";
    let src = SourceFile::new("m.hyb", text);
    assert!(diagnostics(&src, &[]).is_empty());
    for (set, help) in [
        ("lamda=0.5", "did you mean `lambda`?"),
        ("r1.x00=1", "did you mean `r1.x0`?"),
        ("fam[2].x0=21", "`fam.x0` is a family"),
        ("fam.x0[2]=21", "`fam.x0` is a family"),
        ("fam.x=[1; 2; 3]", "`fam.x` is a family"),
        ("z[2]=1", "`z` is a family"),
        ("p=1", "`p` is a family"),
    ] {
        let d = diagnostics(&src, &[set]);
        assert_eq!(d.len(), 1, "{set}: {d:#?}");
        assert_eq!(d[0].code, "E0204", "{set}");
        let h = d[0].help.clone().unwrap_or_default();
        assert!(h.starts_with(help), "{set}: {h}");
        // A suggested name is accepted.
        if let Some(name) = h
            .strip_prefix("did you mean `")
            .and_then(|r| r.split('`').next())
        {
            let again = diagnostics(&src, &[&format!("{name}=1")]);
            assert!(again.is_empty(), "{set} suggests `{name}`: {again:#?}");
        }
    }
}

/// An error in the model's text caused by a value given on the command line
/// says where that value comes from: `every Ts` with `--set Ts=0` was
/// E0304 at `Ts` with nothing about the override. Also through the
/// parameters computed from it, and for a sweep's grid value (an override
/// standing for `--grid`); `k=3`, read by no error, is in no note.
#[test]
fn an_error_caused_by_an_override_names_it() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam Ts = 0.1, k = 2\nparam h = Ts / 2\nstate x = 0\n\
         flow { x' = 1 }\nevery Ts { x+ = 0 }\nevery h { x+ = 1 }\njump up when x >= k { x+ = 0 }\n",
    );
    assert!(diagnostics(&src, &[]).is_empty());
    let d = diagnostics(&src, &["Ts=0", "k=3"]);
    let notes: Vec<(&str, Vec<String>)> = d.iter().map(|d| (d.code, d.notes.clone())).collect();
    assert_eq!(
        notes,
        [
            ("E0304", vec!["Ts = 0 comes from `--set Ts=0`".to_string()]),
            (
                "E0304",
                vec!["Ts = 0 comes from `--set Ts=0` (`h` is computed from it)".to_string()]
            ),
        ],
        "{d:#?}"
    );
    let text = render(&d, &src, false);
    assert!(text.contains("= Ts = 0 comes from `--set Ts=0`"), "{text}");
    // A grid point's value names the grid.
    let grid: Override = "Ts=0".parse().unwrap();
    let d = lang::check_only(&src, &[grid.from_flag("--grid Ts=0")]);
    assert_eq!(d[0].notes, ["Ts = 0 comes from `--grid Ts=0`"], "{d:#?}");
}

/// A state's initial value given on the command line with another shape (`--set x=[1; 2; 3]`
/// for a 2-vector, a user's x0) fails where x is used; those errors say where the value came
/// from, as for a parameter (they named only the model's lines). Also through a parameter the
/// initial value reads.
#[test]
fn a_shape_error_from_a_state_override_names_it() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam A = [0, 1; -1, 0], x0 = [1; 0]\nstate x = x0, z = 1\n\
         flow { x' = A*x; z' = -z }\noutput e = norm(x)\n",
    );
    assert!(diagnostics(&src, &[]).is_empty());
    let d = diagnostics(&src, &["x=[1; 2; 3]", "z=2"]);
    let notes: Vec<(&str, Vec<String>)> = d.iter().map(|d| (d.code, d.notes.clone())).collect();
    assert_eq!(
        notes,
        [(
            "E0301",
            vec!["x = [1; 2; 3] comes from `--set x=[1; 2; 3]`".to_string()]
        )],
        "{d:#?}"
    );
    let d = diagnostics(&src, &["x0=[1; 2; 3]"]);
    assert_eq!(
        d[0].notes,
        ["x0 = [1; 2; 3] comes from `--set x0=[1; 2; 3]` (`x` is computed from it)"],
        "{d:#?}"
    );
}

/// An instance without a value for one of its subsystem's parameters is
/// that error alone: the parameter's uses in the subsystem's body (and the
/// states initialized from it) do not become unknown names.
#[test]
fn a_missing_instance_parameter_does_not_cascade() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nsubsystem S(k) { state y = k; flow { y' = -k * y } }\ns1 = S(kk = 2)\n",
    );
    let diags = diagnostics(&src, &[]);
    let codes: Vec<_> = diags.iter().map(|d| (d.code, d.message.as_str())).collect();
    assert_eq!(
        codes,
        [
            (
                "E0512",
                "`kk` is neither a parameter nor an input of subsystem `S`"
            ),
            ("E0512", "parameter `k` of `s1` (S) has no value"),
        ],
        "{diags:#?}"
    );
}

/// A design constraint's error underlines the constraint alone: its span
/// once ran on to the next statement (the blanks before an optional `;`).
#[test]
fn a_design_constraint_is_underlined_without_the_next_line() {
    let text = "model l\ndesign d {\n    sym P[2]; full U[2, 1]\n    nonsym: [1, 2; 3, 4] * P <= 0   # not symmetric\n    nonsq: U >= 0\n    P > 0\n}\nstate x = 1\n";
    let src = SourceFile::new("m.hyb", text);
    let diags = diagnostics(&src, &[]);
    let spans: Vec<_> = diags
        .iter()
        .map(|d| {
            let s = d.labels[0].span;
            (d.code, &text[s.start..s.end])
        })
        .collect();
    assert_eq!(
        spans,
        [
            ("E0702", "nonsym: [1, 2; 3, 4] * P <= 0"),
            ("E0703", "nonsq: U >= 0")
        ],
        "{diags:#?}"
    );
}

/// A parameter, graph, table, initial value or loop range whose own
/// definition fails is that error alone: what is computed from it
/// (parameters, loops over the graph, what the loop declares, equations of
/// the state, outputs, guards, resets) reports nothing more. Such a name was once declared as the scalar 0, whose uses
/// became shape mismatches, and a failed state's as unknown names.
#[test]
fn a_failed_definition_does_not_cascade() {
    let src = SourceFile::new(
        "m.hyb",
        "model m
param A = [0, 1; 0, 0]
param K = lqr(A, [0; 0], eye(2), 1)
param M = inv([0, 0; 0, 0])
param (Ad, Bd) = c2d(A, [0, 1], 0.1)
param T = table(\"missing.csv\")
graph G = [0, 1; 1]
param Acl = A - [0; 1] * K
state x = [1; 0] * [1; 0]
state v = [1; 0]
output y = v + [1; 2] * [3; 4]
output w = y + 1
flow {
    x' = Acl * x
    v' = Acl * v + M * v + Ad * v + T * v + sum(j in in(G, 1): v)
}
jump hit when w[1] <= 0 && x[1] >= 0 { x+ = -x; v+ = [0; 1] * K * v }
param N = [1, 2] * [3, 4]
for i in 1..N {
    state z[i] = 1
    output o[i] = z[i]
}
flow { for i in 1..N { z[i]' = -z[i] } }
output f = z[1] + o[2] + sum(i in 1..N: z[i])
",
    );
    let diags = diagnostics(&src, &[]);
    let mut found: Vec<_> = diags
        .iter()
        .map(|d| (d.code, d.line_col(&src).unwrap().line))
        .collect();
    // In source order (outputs are checked when first used).
    found.sort_by_key(|&(_, line)| line);
    assert_eq!(
        found,
        [
            ("E0306", 3),
            ("E0306", 4),
            ("E0306", 5),
            ("E0802", 6),
            ("E0301", 7),
            ("E0301", 9),
            ("E0301", 11),
            ("E0301", 18),
        ],
        "{diags:#?}"
    );
}

/// A setting given twice is one too many, not a name clash: the help said "rename one of
/// them", which would make it an unknown setting.
#[test]
fn a_setting_given_twice_is_to_be_removed_not_renamed() {
    for (text, help) in [
        (
            "model m\nstate x = 1\nflow { x' = -x }\nsim { T = 10; T = 5 }\n",
            "remove one of them: `T` takes one value",
        ),
        (
            "model m\nstate x = 1\nflow { x' = -x }\nlog { every = 2; every = 3 }\n",
            "remove one of them: `every` takes one value",
        ),
        (
            "model m\nparam k = 1\nstate x = 1\nflow { x' = -k*x }\nsweep { k in [1, 2]; k in [3] }\n",
            "remove one of them: `k` takes one value",
        ),
        (
            "model m\nparam k = 1\nstate x = 1\nflow { x' = -k*x }\nsweep { runs = 2 }\nsweep { runs = 3 }\n",
            "write all the entries in one `sweep` block",
        ),
    ] {
        let src = SourceFile::new("m.hyb", text);
        let d = diagnostics(&src, &[]);
        assert_eq!(d.len(), 1, "{text}: {d:#?}");
        assert_eq!(d[0].code, "E0202", "{text}: {d:#?}");
        let shown = render(&d, &src, false);
        assert!(shown.contains(help) && !shown.contains("rename"), "{shown}");
    }
}

/// A state whose initial value reads another state (`state x = [a; b]` with `a`, `b` drawn
/// states, as a HyEQ user writes x0) is that error alone: its equations, resets, outputs and
/// properties reported it as an unknown name six times more ("did you mean `xh`?").
#[test]
fn a_state_initialized_from_states_does_not_cascade() {
    let src = SourceFile::new(
        "m.hyb",
        "model m
state a ~ uniform(-1, 1), b = 0
state x = [a; b], xh = [0; 0]
flow { x' = -x; xh' = -xh }
every 0.5 { xh+ = xh + (x - xh) }
output e = norm(x - xh)
property p: at jumps step norm(post(x - xh)) <= norm(x - xh)
",
    );
    let diags = diagnostics(&src, &[]);
    let found: Vec<_> = diags
        .iter()
        .map(|d| (d.code, d.line_col(&src).unwrap().to_string()))
        .collect();
    assert_eq!(found, [("E0305", "3:11".to_string())], "{diags:#?}");
}

/// A state declared without its initial value (E0504) is still a state:
/// its flow equation, guards, resets and outputs add no "unknown name".
#[test]
fn a_state_without_initial_value_does_not_cascade() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nstate x, y = 1\nflow { x' = -x; y' = x }\njump r when x <= 0.5 { x+ = 1 }\noutput o = 2*x\n",
    );
    let diags = diagnostics(&src, &[]);
    let found: Vec<_> = diags
        .iter()
        .map(|d| (d.code, d.line_col(&src).unwrap().to_string()))
        .collect();
    assert_eq!(found, [("E0504", "2:7".to_string())], "{diags:#?}");
}

/// A rule that fails its checks (`every Ts` with `Ts = 0`) is still a known
/// name: a property naming it adds no "unknown name" to the real errors.
#[test]
fn a_failed_rule_is_still_a_known_name() {
    let path = format!("{}/models/sample_and_hold.hyb", env!("CARGO_MANIFEST_DIR"));
    let src = SourceFile::read(path).unwrap();
    let diags = diagnostics(&src, &["Ts=0"]);
    let codes: Vec<_> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["E0306", "E0304"], "{diags:#?}");
}

/// A misspelt first word of a property's body gets the closest of the
/// body's words, as a misspelt keyword does (the words are contextual, not
/// keywords).
#[test]
fn a_misspelt_property_word_gets_the_closest_one() {
    for (body, word) in [
        ("allways x >= 0", "always"),
        ("evntually within 1 x <= 0.5", "eventually"),
        ("nonincresing x at jumps", "nonincreasing"),
        ("durring flows x >= 0", "during"),
    ] {
        let text = format!("model m\nstate x = 1\nflow {{ x' = -x }}\nproperty p: {body}\n");
        let src = SourceFile::new("m.hyb", text);
        let diags = diagnostics(&src, &[]);
        let d = diags.first().expect("an error");
        assert_eq!(
            (d.code, d.line_col(&src).unwrap().to_string()),
            ("E0101", "4:13".to_string()),
            "{body}: {d:#?}"
        );
        let help = format!("did you mean `{word}`?");
        assert_eq!(d.help.as_deref(), Some(help.as_str()), "{body}: {d:#?}");
    }
}

/// An index error in a `for` loop points at the loop with the iteration's
/// variables, and names the `--set` values its range reads (a range grown
/// past a table by `--set N=5`); a state member whose value failed is not
/// reported again at its flow equation.
#[test]
fn an_index_error_in_a_loop_names_the_iteration_and_the_override_of_its_range() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam N = 3\nparam d = [1, 2, 3]\nfor i in 1..N {\n    state x[i] = d[i]\n}\nflow {\n    for i in 1..N {\n        x[i]' = -x[i]\n    }\n}\n",
    );
    let d = diagnostics(&src, &["N=5"]);
    assert_eq!(d.len(), 2, "{d:#?}");
    let text = render(&d, &src, false);
    for (k, i) in [(0, 4), (1, 5)] {
        assert_eq!(d[k].code, "E0401");
        assert_eq!(d[k].message, format!("index {i} is out of range 1..3"));
    }
    assert!(
        text.contains("4 │ for i in 1..N {\n  │     --------- in the iteration with `i` = 4"),
        "{text}"
    );
    assert!(
        text.contains("= the loop's range reads `N`, set by `--set N=5`"),
        "{text}"
    );
    // Without an override the loop's own note only.
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam d = [1, 2]\nfor i in 1..3 { for k in 1..2 { state x[i, k] = d[i] } }\n",
    );
    let d = diagnostics(&src, &[]);
    let text = render(&d, &src, false);
    // `d[i]` does not read `k`: lowered (and failed) once per `i`.
    assert_eq!(d.len(), 1, "{text}");
    assert!(text.contains("in the iteration with `k` = 1"), "{text}");
    assert!(text.contains("in the iteration with `i` = 3"), "{text}");
    assert!(!text.contains("range reads"), "{text}");
}

/// A family too large for its limit because of an override (`--set
/// N=100000`) names the override its loop's range reads, at the loop (it
/// pointed at the declaration alone, the note on `--set` missing); sized so
/// by the model's own text it reads as before.
#[test]
fn a_family_over_its_limit_names_the_override_of_its_range() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam N = 3\nfor i in 1..N {\n    state x[i] = 0\n}\nflow { for i in 1..N { x[i]' = 1 } }\n",
    );
    let d = diagnostics(&src, &["N=100000"]);
    assert_eq!(d.len(), 1, "{d:#?}");
    assert_eq!(d[0].code, "E0307");
    assert_eq!(d[0].line_col(&src).unwrap().to_string(), "4:11");
    let text = render(&d, &src, false);
    for want in [
        "100000 scalar states: over the limit of 20000",
        "3 │ for i in 1..N {\n  │     --------- the range of this loop",
        "= the loop's range reads `N`, set by `--set N=100000`",
    ] {
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
    let src = SourceFile::new("m.hyb", "model m\nfor i in 1..100000 { state x[i] = 0 }\n");
    let text = render(&diagnostics(&src, &[]), &src, false);
    assert!(text.contains("100000 scalar states"), "{text}");
    assert!(!text.contains("range"), "{text}");
}

/// A model whose states are all in families sized 0 by an override says
/// which override emptied it.
#[test]
fn a_model_emptied_by_an_override_names_it() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam N = 3\nfor i in 1..N { state x[i] = 0 }\nflow { for i in 1..N { x[i]' = 1 } }\n",
    );
    let d = diagnostics(&src, &["N=0"]);
    assert_eq!(d.len(), 1, "{d:#?}");
    assert_eq!(
        d[0].message,
        "expected at least one state component (`state x = ...`, or a family of size ≥ 1), found a model without states with `--set N=0`"
    );
    let d = diagnostics(&src, &[]);
    assert!(d.is_empty(), "{d:#?}");
}

/// A C or MATLAB habit, `state x[2] = [1; 0]` for a vector of two entries, declares the one
/// member `x[2]` of a family: the first error at `x` or `x[1]` says so and how to declare the
/// vector (once per family); a family with several members or only `x[1]` gets no such help.
#[test]
fn a_lone_family_member_declared_as_a_vector_says_how_to_declare_one() {
    let src = SourceFile::new(
        "m.hyb",
        "model m\nparam A = [0, 1; -1, 0]\nstate x[2] = [1; 0]\nflow { x' = A*x }\njump when x[1] <= 0 { x+ = -x }\n",
    );
    let ds = diagnostics(&src, &[]);
    let codes: Vec<&str> = ds.iter().map(|d| d.code).collect();
    assert_eq!(
        codes,
        ["E0403", "E0403", "E0402", "E0403", "E0403"],
        "{ds:?}"
    );
    let helped: Vec<_> = ds.iter().filter(|d| d.help.is_some()).collect();
    assert_eq!(helped.len(), 1, "{ds:?}");
    let help = helped[0].help.as_deref().unwrap();
    assert!(
        help.contains("`state x[2] = …` declares one member")
            && help.contains("`state x = [a; b; …]` (or `zeros(2, 1)`)"),
        "{help}"
    );
    for text in [
        "model m\nstate x[1] = 0\nflow { x' = 1 }\n",
        "model m\nfor i in 1..2 { state x[i] = 0 }\nflow { x[1]' = x[3] }\n",
    ] {
        let ds = diagnostics(&SourceFile::new("m.hyb", text), &[]);
        assert!(
            !ds.is_empty() && ds.iter().all(|d| d.help.is_none()),
            "{text}: {ds:?}"
        );
    }
}
