use super::ast::*;
use super::*;

#[test]
fn parses_the_bouncing_ball() {
    let m = parse_model(
        "model bouncing_ball\nparam g = 9.81, lambda = 0.8\nstate h = 1, v = 0\n\
         flow { h' = v; v' = -g } in h >= 0 || v >= 0\n\
         jump impact when h <= 0 && v < 0 { v+ = -lambda * v }\n\
         sim { T = 10; J = 200; priority = jumps }\n",
    )
    .unwrap();
    assert_eq!(m.name.name, "bouncing_ball");
    assert_eq!(m.items.len(), 5);
    let Item::Flow(f) = &m.items[2] else { panic!() };
    assert_eq!(f.stmts.len(), 2);
    assert!(matches!(
        f.set.as_ref().unwrap().kind,
        ExprKind::Binary(BinOp::Or, _, _)
    ));
}

#[test]
fn a_model_fits_on_one_line_with_semicolons() {
    // `;` separates statements as a newline does, after the header too
    // (`model m; state x = 1` was E0101 at the `;`).
    let one = parse_model("model m; state x = 1; flow { x' = -x }; sim { T = 1 }").unwrap();
    let lines = parse_model("model m\nstate x = 1\nflow { x' = -x }\nsim { T = 1 }\n").unwrap();
    assert_eq!(one.name.name, "m");
    assert_eq!(one.items.len(), 3);
    assert_eq!(one.items.len(), lines.items.len());
    assert!(parse_model("model m;; state x = 1").is_err());
}
#[test]
fn precedence_and_postfix() {
    let e = parse_expr("-a*b' + c[1, 2:3]^2 < 3 && !d").unwrap();
    let ExprKind::Binary(BinOp::And, l, r) = e.kind else {
        panic!()
    };
    assert!(matches!(r.kind, ExprKind::Unary(UnOp::Not, _)));
    let ExprKind::Binary(BinOp::Lt, sum, _) = l.kind else {
        panic!()
    };
    let ExprKind::Binary(BinOp::Add, prod, pow) = sum.kind else {
        panic!()
    };
    let ExprKind::Binary(BinOp::Mul, neg, tr) = prod.kind else {
        panic!()
    };
    assert!(matches!(neg.kind, ExprKind::Unary(UnOp::Neg, _)));
    assert!(matches!(tr.kind, ExprKind::Unary(UnOp::Transpose, _)));
    assert!(matches!(pow.kind, ExprKind::Binary(BinOp::Pow, _, _)));
}

#[test]
fn syntax_errors_speak_plainly() {
    let err = parse_model("model m\nstate x = 1 +\n").unwrap_err();
    let d = err.to_diagnostic();
    assert!(
        d.message.contains("expected an expression"),
        "{}",
        d.message
    );
    assert!(
        !d.message.replace("expression", "").contains("expr"),
        "{}",
        d.message
    );
    // Just past the `+` on its line, not at the empty line after it.
    assert_eq!(err.span().start, 21);
}

/// A word is never expected where it was found: `when` after a flow block
/// (a flow set written as a guard) is not "expected `when` or `every`" (an
/// `every` rule may start a declaration there, `when` may not), while
/// after `jump NAME` both are.
#[test]
fn an_unexpected_when_is_not_expected() {
    let err = parse_model("model m\nstate x = 0\nflow { x' = 1 } when x >= 0\n").unwrap_err();
    let message = err.to_diagnostic().message;
    assert!(
        message.starts_with("unexpected `when`; expected "),
        "{message}"
    );
    assert!(
        !message.contains("; expected `when`") && !message.contains(", `when`"),
        "{message}"
    );
    assert!(message.contains("`every`"), "{message}");
    let err = parse_model("model m\nstate x = 0\njump reset x >= 1 { x+ = 0 }\n").unwrap_err();
    let message = err.to_diagnostic().message;
    assert_eq!(message, "unexpected `x`; expected `[`, `every` or `when`");
}

/// Python's operator words are E0105 like MATLAB's operators, at the word:
/// where the parse stops on it (`or`) or just after it (`and`, `not`, read
/// as a name).
#[test]
fn python_operator_words_name_hybsims() {
    for (src, word, write, at) in [
        (
            "model m\nstate x = 0\nflow { x' = 1 } in x >= 0 and x <= 5\n",
            "and",
            "&&",
            46,
        ),
        (
            "model m\nstate x = 0\njump r when x >= 1 or x < 0 { x+ = 0 }\n",
            "or",
            "||",
            39,
        ),
        (
            "model m\nstate x = 0\njump r when not x >= 1 { x+ = 0 }\n",
            "not",
            "!",
            32,
        ),
    ] {
        let err = parse_model(src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0105", "{src}");
        assert_eq!(
            d.message,
            format!("`{word}` is Python's spelling; hybsim writes `{write}`")
        );
        assert_eq!(&src[err.span().start..err.span().end], word, "{src}");
        assert_eq!(err.span().start, at, "{src}");
    }
}

#[test]
fn deep_nesting_is_an_error_not_a_crash() {
    let deep = format!(
        "model m\nparam a = {}1{}\n",
        "(".repeat(10_000),
        ")".repeat(10_000)
    );
    assert!(matches!(
        parse_model(&deep),
        Err(SyntaxError::TooDeep { .. })
    ));
    let pow = format!("model m\nparam a = 2{}\n", "^2".repeat(10_000));
    assert!(matches!(
        parse_model(&pow),
        Err(SyntaxError::TooDeep { .. })
    ));
}

/// HyEQ's `dx1 = x2` in a flow block is E0107 at the name, with the
/// equation to write; `==` and names outside flow blocks are not.
#[test]
fn a_flow_equation_without_a_prime_says_how_to_write_it() {
    let src = "model m\nstate x1 = 1, x2 = 0\nflow {\n  dx1 = x2\n  dx2 = -1\n}\n";
    let err = parse_model(src).unwrap_err();
    let d = err.to_diagnostic();
    assert_eq!(d.code, "E0107");
    assert_eq!(&src[err.span().start..err.span().end], "dx1");
    assert!(d.message.contains("`x' = ...`"), "{}", d.message);
    assert!(
        d.help.iter().any(|h| h.contains("write `x1' = ...`")),
        "{:?}",
        d.help
    );
    // Elsewhere a stray `=` is not E0107 (in a guard it is `==`, E0109).
    let err = parse_model("model m\nstate x = 1\njump r when x = 1 { x+ = 0 }\n").unwrap_err();
    assert_eq!(err.to_diagnostic().code, "E0109");
}

/// `x+` read on a reset's right side or in a condition is E0109 at `x+`,
/// saying to read `x`; a sum `x + 1` and an unfinished `x + }` are not.
#[test]
fn reading_the_post_jump_state_says_to_read_the_pre_jump_one() {
    for (src, name) in [
        (
            "model m\nstate x = 0\njump when x >= 1 { x+ = x+ + 1 }\n",
            "x+",
        ),
        (
            "model m\nstate x = 0\njump when x >= 1 { x+ = 2 * x+ }\n",
            "x+",
        ),
        (
            "model m\nstate x[2] = 0\njump when x[1]+ >= 1 { x[1]+ = 0 }\n",
            "x[1]+",
        ),
        (
            "model m\nstate x = 0\njump when x >= 1 { x+ = ball.h+ * 2 }\n",
            "ball.h+",
        ),
    ] {
        let err = parse_model(src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0109", "{src}: {}", d.message);
        assert_eq!(&src[err.span().start..err.span().end], name, "{src}");
        let pre = name.trim_end_matches('+');
        assert!(
            d.help.iter().any(|h| h.contains(&format!("write `{pre}`"))),
            "{:?}",
            d.help
        );
    }
    assert!(parse_model("model m\nstate x = 0\njump when x >= 1 { x+ = x + 1 }\n").is_ok());
    let err = parse_model("model m\nstate x = 0\nflow { x' = x + }\n").unwrap_err();
    assert_eq!(err.to_diagnostic().code, "E0101");
}

/// `:=` (Pascal, Modelica, Python) is E0109 at the `:=` wherever the parse
/// stopped on its line: in a flow block it read as a flow equation outside
/// its block, in a reset as no declaration, in `param` as a missing value.
#[test]
fn an_assignment_written_colon_equals_says_to_write_equals() {
    for body in [
        "flow { x' := 1 }",
        "jump when x >= 1 { x+ := 0 }",
        "param k := 2",
        "state y := 2",
    ] {
        let src = format!("model m\nstate x = 0\n{body}\n");
        let err = parse_model(&src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0109", "{src}: {}", d.message);
        assert_eq!(&src[err.span().start..err.span().end], ":=", "{src}");
    }
    // In a comment it is not the error.
    let err = parse_model("model m\nstate x = 0\nflow { x' = } # x := 0\n").unwrap_err();
    assert_eq!(err.to_diagnostic().code, "E0101");
}

/// A flow set written after a jump's block, as if it were the jump's, is
/// E0109 at the `in`, saying where C is written.
#[test]
fn a_flow_set_after_a_jump_block_says_where_c_goes() {
    for jump in [
        "jump r when x >= 1 { x+ = 0 } in x <= 1",
        "jump r when x >= 1 {\n  x+ = 0\n}\nin x <= 1",
        "jump r every 1 { x+ = 0 } in x <= 1",
    ] {
        let src = format!("model m\nstate x = 0\nflow {{ x' = 1 }}\n{jump}\n");
        let err = parse_model(&src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0109", "{src}: {}", d.message);
        assert_eq!(&src[err.span().start..err.span().end], "in", "{src}");
        assert!(
            d.message.contains("flow set belongs to the flow block"),
            "{}",
            d.message
        );
    }
}

/// A block left open where the next declaration (or the flow set, or the
/// end of the file) begins is E0108 there, pointing at the open `{`.
#[test]
fn an_unclosed_block_points_at_its_brace() {
    for (src, found) in [
        ("model m\nstate x = 1\nflow {\n  x' = -x\nin x >= 0\n", "in"),
        (
            "model m\nstate x = 1\nflow { x' = -x\njump r when x <= 0 { x+ = 1 }\n",
            "jump",
        ),
        ("model m\nstate x = 1\nsim { T = 1\n", ""),
    ] {
        let err = parse_model(src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0108", "{src}: {}", d.message);
        assert_eq!(&src[err.span().start..err.span().end], found, "{src}");
        let SyntaxError::Unclosed { open, .. } = err else {
            panic!()
        };
        assert_eq!(&src[open.start..open.end], "{", "{src}");
    }
    // Inside a block, a misplaced keyword that is not at a line's start
    // stays the plain syntax error.
    let err = parse_model("model m\nstate x = 1\nflow { x' = in }\n").unwrap_err();
    assert_eq!(err.to_diagnostic().code, "E0101");
}

/// A `(` or `[` left open where a closing delimiter of another kind, the
/// next declaration or the end of the file comes is E0108 there, pointing
/// at the open delimiter (it was "unexpected `}`" at the block's end).
#[test]
fn an_unclosed_parenthesis_or_bracket_points_at_it() {
    for (src, found, open) in [
        (
            "model m\nstate x = 1\nflow {\n    x' = -(x + 1\n}\n",
            "}",
            "(",
        ),
        ("model m\nparam a = (1 + 2\nstate x = 1\n", "state", "("),
        (
            "model m\nparam A = [1, 2; 3, 4\nstate x = 1\n",
            "state",
            "[",
        ),
        ("model m\nstate x = 1\nflow { x' = -(x + [1)] }\n", ")", "["),
        ("model m\nstate x = 1\nflow { x' = max(x, (1 }\n", "}", "("),
        ("model m\nparam a = (1 + 2 # a comment (\n", "", "("),
    ] {
        let err = parse_model(src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0108", "{src}: {}", d.message);
        let SyntaxError::Unclosed {
            open: at, delim, ..
        } = err
        else {
            panic!("{src}")
        };
        assert_eq!(&src[at.start..at.end], open, "{src}");
        assert_eq!(delim.to_string(), open, "{src}");
        if !found.is_empty() {
            assert_eq!(&src[err.span().start..err.span().end], found, "{src}");
        }
        assert!(
            d.message.starts_with(&format!("`{open}` not closed")),
            "{}",
            d.message
        );
    }
    // Inside a group the parser's other stops stay what they were: a
    // missing operator between two entries is no unclosed group.
    let err = parse_model("model m\nparam a = (1 2)\n").unwrap_err();
    assert_ne!(err.to_diagnostic().code, "E0108");
}

/// Another language's spelling where the parse stops is E0109 at what was
/// written, naming hybsim's: the habits of a MATLAB (HyEQ) user first.
#[test]
fn foreign_spellings_name_hybsims() {
    for (src, at, says) in [
        ("model m\n% MATLAB comment\nstate x = 1\n", "%", "`#`"),
        ("model m\nstate x = 1 // C comment\n", "//", "`#`"),
        ("model m\nstate x = 1\nflow { x' = -x.^2 }\n", ".^", "`^`"),
        ("model m\nparam A = eye(2).'\n", ".'", "`'`"),
        ("model m\nstate x = 1\nflow { x' = -x**2 }\n", "**", "`^`"),
        ("model m\nstate x = .5\n", ".5", "`0.5`"),
        (
            "model m\nstate x = 1, v = 0\nflow { x'' = -x }\n",
            "''",
            "first derivative",
        ),
        (
            "model m\nstate x = [1; 2]\nflow { x(1)' = x(2) }\n",
            "x(",
            "`x[...]`",
        ),
        ("model m\nstate x(0) = 1\n", "x(", "`x[...]`"),
        (
            "model m\nstate x = 1\njump r when x = 0 { x+ = 1 }\n",
            "=",
            "`==`",
        ),
        (
            "model m\nstate x = 1\nflow { x' = -1 } in x = 0\n",
            "=",
            "`==`",
        ),
        ("model m\nparam p = if 1 = 2 then 1 else 0\n", "=", "`==`"),
        (
            "model m\nstate x = 1\nflow { x' = -x } x >= 0\n",
            "}",
            "`in`",
        ),
        (
            "model m\nstate x = 1\nflow { x' = -x }\nend\n",
            "end",
            "no `end`",
        ),
        ("model m\nparam A = [0 1; -1 0]\n", "1", "`,`"),
        ("model m\nparam A = [sin(1) cos(1)]\n", "cos", "`,`"),
        // A sign glued to the next entry: MATLAB's second entry, or a difference?
        ("model m\nparam b = [0 -1]\n", "-", "ambiguous `-`"),
        ("model m\nparam b = [1, a +b]\n", "+", "ambiguous `+`"),
        ("model m\nparam A = [1, 2; 3 -x[1]]\n", "-", "ambiguous `-`"),
        ("model m\nparam A = [2*a -(b)]\n", "-", "ambiguous `-`"),
        (
            "model m\nparam p = if 1 > 2 then 1 elseif 1 > 0 then 2 else 3\n",
            "elseif",
            "`else if`",
        ),
        (
            "model m\nparam p = if 1 > 2 then 1 elif 1 > 0 then 2 else 3\n",
            "elif",
            "`else if`",
        ),
        (
            "model m\nparam p = if 1 > 2 then 1 else0\n",
            "else0",
            "`else`",
        ),
        (
            "model m\nparam p = if 1 > 2 then1 else 0\n",
            "then1",
            "`then`",
        ),
    ] {
        let err = parse_model(src).unwrap_err();
        let d = err.to_diagnostic();
        assert_eq!(d.code, "E0109", "{src}: {}", d.message);
        assert_eq!(&src[err.span().start..err.span().end], at, "{src}");
        assert!(d.message.contains(says), "{src}: {}", d.message);
    }
    // What parses stays as it was: `x.*y`, `0.5`, calls, comparisons.
    parse_model(
        "model m\nparam a = [1, 2] .* [3, 4], b = 0.5 ^ 2, c = sin(0.5)\n\
         state x = 1\nflow { x' = -x } in x >= 0 && b != 1\n",
    )
    .unwrap();
}

/// `[0 -1]` is refused (E0109 at the `-`), saying both readings; spaced or
/// glued operators, a sign after a comma and parenthesised or indexed
/// expressions inside `[ ]` keep parsing as they did.
#[test]
fn a_sign_glued_to_the_next_entry_is_ambiguous() {
    let err = parse_expr("[0 -1]").unwrap_err();
    assert_eq!(err.span(), crate::source::Span::new(3, 4));
    let d = err.to_diagnostic();
    assert_eq!(d.code, "E0109");
    let help = d.help.unwrap_or_default();
    assert!(
        help.contains("`[0, -1]` for two entries") && help.contains("`[0 - 1]` for the difference"),
        "{help}"
    );
    let err = parse_expr("[a +b]").unwrap_err();
    let help = err.to_diagnostic().help.unwrap_or_default();
    assert!(help.contains("`[a, b]`"), "{help}");
    for ok in [
        "[0 - 1]",
        "[0-1]",
        "[0, -1]",
        "[-1, 0]",
        "[a - -b]",
        "[f(a -b)]",
        "[(a -b), 1]",
        "x[i -1]",
        "[x[i -1], 2]",
        "[sum(k in 1..2: k -1)]",
        "[a -\n b]",
        "a -b",
    ] {
        parse_expr(ok).unwrap_or_else(|e| panic!("{ok}: {e}"));
    }
    // The blocks of a matrix inequality are matrix entries too.
    let err = parse_model("model m\ndesign d {\n  sym P[2]\n  [P -P; P, P] > 0\n}\n").unwrap_err();
    assert_eq!(err.to_diagnostic().code, "E0109");
}

/// Keywords are whole words: `elseif`, `paramx = 1`, `for i in1..3` are not
/// read as `else if`, `param x = 1`, `in 1..3`; names that start with a
/// keyword stay names everywhere a name goes.
#[test]
fn keywords_are_whole_words() {
    for src in [
        "model m\nparamx = 1\n",
        "model m\nstatex = 1\n",
        "model m\nparam p = if 1 > 2 then 1 elseif 1 > 0 then 2 else 3\n",
        "model m\nstate x = 1\nflow { x' = -x } infalse\n",
        "model m\nstate x = [1; 2]\nfor i in1..2 { output y[i] = x[i] }\n",
        "model m\nstate x = 1\njump r whenx >= 1 { x+ = 0 }\n",
        "model m\nparam p = sumk(k in 1..2: k)\n",
    ] {
        assert!(parse_model(src).is_err(), "{src}");
    }
    let m = parse_model(
        "model modelled\n\
         param elsewhere = 1, input = 2, iffy = 3, thenceforth = 4, summer = 5, outer = 6\n\
         param edges1 = 1, informal = 2, format = 3, simple = 4, designer = 5, whence = 6\n\
         state everyone = 1, flows = 0, jumper = 0, stateful = 0, params = 0, graphs = 0, noisy = 0\n\
         output outputs = if iffy > 0 then elsewhere else thenceforth\n\
         flow { everyone' = -everyone * input; flows' = 1 } in everyone >= informal - 2\n\
         for iffy2 in 1..2 { output ifs[iffy2] = iffy2 * summer }\n\
         jump elseif when flows >= 1 { flows+ = 0 }\n\
         output total = sum(insider in 1..3: insider * outer)\n",
    )
    .unwrap();
    assert_eq!(m.name.name, "modelled");
    assert_eq!(m.items.len(), 8);
}
