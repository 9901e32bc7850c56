//! `hybsim plot run.mcap`: HyEQ's plots from a logged file, by the same
//! sink as `hybsim run --plot` (the same figure, byte for byte, when the
//! file holds what the run's plot saw); the `hybrid` kind in 3-D; PNG by
//! the file extension; unreadable files and unknown names exit 2.

use std::path::{Path, PathBuf};

use super::util::{code, hybsim, stderr};

fn model(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models")
        .join(name)
}

/// The texts of an SVG's `<text>` elements.
fn texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|s| {
            let body = &s[s.find('>')? + 1..];
            Some(body[..body.find("</text>")?].trim().to_string())
        })
        .collect()
}

/// Runs `hybsim ARGS` in `dir` and asserts it succeeded.
fn ok(dir: &Path, args: &[&str]) {
    let out = hybsim(dir, args);
    assert_eq!(code(&out), 0, "{args:?}: {}", stderr(&out));
}

/// Width and height of a PNG file, after decoding all of it.
fn png_size(path: &Path) -> (u32, u32) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut buf).unwrap();
    // A drawing, not a blank canvas: more than one colour.
    let first = &buf[..3];
    assert!(
        buf[..frame.buffer_size()].chunks(3).any(|p| p != first),
        "{} is blank",
        path.display()
    );
    (frame.width, frame.height)
}

#[test]
fn plots_from_a_file_are_the_plots_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    let ball = ball.to_str().unwrap();
    for (kind, vars) in [
        ("flows", "h,v"),
        ("jumps", "h"),
        ("hybrid", "h,v"),
        ("phase", "h,v"),
        ("domain", "h"),
    ] {
        let live = format!("live-{kind}.svg");
        let mcap = format!("{kind}.mcap");
        ok(
            d,
            &[
                "run",
                ball,
                "-q",
                "-o",
                &mcap,
                "--plot",
                &live,
                "--plot-kind",
                kind,
                "--plot-vars",
                vars,
            ],
        );
        let file = format!("file-{kind}.svg");
        ok(
            d,
            &["plot", &mcap, "--kind", kind, "--vars", vars, "-o", &file],
        );
        let (live, file) = (
            std::fs::read_to_string(d.join(live)).unwrap(),
            std::fs::read_to_string(d.join(file)).unwrap(),
        );
        assert!(
            live == file,
            "{kind}: the plot of the file differs from the run's"
        );
    }
    // A paper model: a family member and an output, read back from the file.
    let m = model("intermittent_estimation.hyb");
    ok(
        d,
        &[
            "run",
            m.to_str().unwrap(),
            "-q",
            "--T",
            "1",
            "-o",
            "ie.mcap",
            "--plot",
            "live.svg",
            "--plot-vars",
            "xhat[2],enorm",
        ],
    );
    ok(
        d,
        &["plot", "ie.mcap", "--vars", "xhat[2],enorm", "-o", "ie.svg"],
    );
    let svg = std::fs::read_to_string(d.join("ie.svg")).unwrap();
    let labels = texts(&svg);
    for name in ["xhat[2][1]", "enorm", "t"] {
        assert!(
            labels.iter().any(|l| l == name),
            "no `{name}` in {labels:?}"
        );
    }
    assert!(!labels.iter().any(|l| l == "xhat[1][1]"), "one member only");
    assert_eq!(svg, std::fs::read_to_string(d.join("live.svg")).unwrap());
}

/// Single components named as in CSV (`x[2]`, `xhat[2][1]`, spaces
/// allowed) select one series each: a phase plot of a vector state's
/// first two components, from a run and from its file alike; a component
/// that does not exist exits 2 and names the forms.
#[test]
fn components_of_vectors_and_family_members_are_selected_one_by_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sh = model("sample_and_hold.hyb");
    ok(
        d,
        &[
            "run",
            sh.to_str().unwrap(),
            "-q",
            "-o",
            "sh.mcap",
            "--plot",
            "live.svg",
            "--plot-kind",
            "phase",
            "--plot-vars",
            "x[1], x[2]",
        ],
    );
    ok(
        d,
        &[
            "plot",
            "sh.mcap",
            "--kind",
            "phase",
            "--vars",
            "x[1],x[2]",
            "-o",
            "file.svg",
        ],
    );
    let live = std::fs::read_to_string(d.join("live.svg")).unwrap();
    assert_eq!(live, std::fs::read_to_string(d.join("file.svg")).unwrap());
    let labels = texts(&live);
    for name in ["x[1]", "x[2]"] {
        assert!(
            labels.iter().any(|l| l == name),
            "no `{name}` in {labels:?}"
        );
    }
    // A member's component and an output, flows.
    let m = model("intermittent_estimation.hyb");
    let m = m.to_str().unwrap();
    ok(
        d,
        &[
            "run",
            m,
            "-q",
            "--T",
            "0.5",
            "-o",
            "ie.mcap",
            "--plot",
            "c.svg",
            "--plot-vars",
            "xhat[2][1],enorm",
        ],
    );
    let labels = texts(&std::fs::read_to_string(d.join("c.svg")).unwrap());
    assert!(labels.iter().any(|l| l == "xhat[2][1]"), "{labels:?}");
    assert!(
        !labels.iter().any(|l| l == "xhat[2][2]"),
        "one component only: {labels:?}"
    );
    for args in [
        &[
            "run",
            sh.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--plot",
            "x.svg",
            "--plot-vars",
            "x[40]",
        ][..],
        &["plot", "sh.mcap", "--vars", "x[0]", "-o", "x.svg"][..],
    ] {
        let o = hybsim(d, args);
        assert_eq!(code(&o), 2, "{args:?}: {}", stderr(&o));
        // The entry's indices, not "neither a state nor an output" of an `x`
        // that is one.
        assert!(
            stderr(&o).contains(
                "`x` is a vector of 39: its components are `x[1]` to `x[39]` (indices start at 1)"
            ),
            "{}",
            stderr(&o)
        );
        assert!(!d.join("x.svg").exists());
    }
    // `--log-vars` selects entries whole; a family's member out of range.
    for (vars, says) in [
        (
            "x[1]",
            "`--log-vars x[1]`: `x` is selected whole (its components are not chosen one by one): write `x`",
        ),
        (
            "K[1]",
            "`--log-vars K[1]`: neither a state nor an output of the model",
        ),
    ] {
        let o = hybsim(
            d,
            &[
                "run",
                sh.to_str().unwrap(),
                "-q",
                "--no-mcap",
                "--csv",
                "x.csv",
                "--log-vars",
                vars,
            ],
        );
        assert_eq!(code(&o), 2, "{vars}: {}", stderr(&o));
        assert!(stderr(&o).contains(says), "{vars}: {}", stderr(&o));
    }
    let o = hybsim(
        d,
        &[
            "run",
            m,
            "-q",
            "--T",
            "0.1",
            "--no-mcap",
            "--plot",
            "x.svg",
            "--plot-vars",
            "xhat[7]",
        ],
    );
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("the family `xhat` has the members `xhat[1]` to `xhat[3]`"),
        "{}",
        stderr(&o)
    );
}

/// HyEQ's `plotHybrid`: one 3-D panel per entry, axes t, j and the entry,
/// flows solid, jumps dashed; from a run and from a file, ball and a paper
/// model.
#[test]
fn the_hybrid_kind_draws_components_over_t_and_j() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    ok(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--plot",
            "h.svg",
            "--plot-kind",
            "hybrid",
        ],
    );
    let svg = std::fs::read_to_string(d.join("h.svg")).unwrap();
    let labels = texts(&svg);
    for s in ["t", "j", "h", "v", "bouncing_ball: h", "bouncing_ball: v"] {
        assert!(labels.iter().any(|l| l == s), "no text `{s}` in {labels:?}");
    }
    // 20 jumps of h and of v, each a dashed segment (several dashes).
    assert!(svg.matches("<polyline").count() > 40, "jumps not drawn");
    let m = model("consensus_estimation.hyb");
    ok(
        d,
        &[
            "run",
            m.to_str().unwrap(),
            "-q",
            "--T",
            "0.5",
            "-o",
            "c.mcap",
        ],
    );
    ok(
        d,
        &[
            "plot", "c.mcap", "--kind", "hybrid", "--vars", "err", "-o", "c.svg",
        ],
    );
    let labels = texts(&std::fs::read_to_string(d.join("c.svg")).unwrap());
    for s in ["t", "j", "err"] {
        assert!(labels.iter().any(|l| l == s), "no text `{s}` in {labels:?}");
    }
}

/// The tick at zero of an axis symmetric about it reads `0.0`: plotters places ticks at
/// `start + k·step`, and the one at 0 came out as -3e-17 and was labelled `-0.0` (an
/// oscillator's x and y, flows and phase plots).
#[test]
fn the_zero_tick_has_no_sign() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("osc.hyb"),
        "model osc\nstate x = 1, y = 0\nflow { x' = y; y' = -x }\nsim { T = 10 }\n",
    )
    .unwrap();
    for kind in ["flows", "phase", "hybrid"] {
        let svg = format!("{kind}.svg");
        ok(
            d,
            &[
                "run",
                "osc.hyb",
                "-q",
                "--no-mcap",
                "--plot",
                &svg,
                "--plot-kind",
                kind,
            ],
        );
        let labels = texts(&std::fs::read_to_string(d.join(&svg)).unwrap());
        assert!(
            labels.iter().any(|l| l == "0.0"),
            "{kind}: no zero tick in {labels:?}"
        );
        assert!(
            !labels
                .iter()
                .any(|l| l.starts_with('-') && l.trim_matches(['-', '0', '.']).is_empty()),
            "{kind}: a signed zero in {labels:?}"
        );
    }
}

/// PNG by the extension, for `--plot` and `hybsim plot`: a decodable image
/// of the figure's size (900 wide, 260 per panel; 460 per 3-D panel).
#[test]
fn png_plots_decode_with_the_figure_size() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    ok(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "-o",
            "b.mcap",
            "--plot",
            "b.png",
            "--plot-vars",
            "h,v",
        ],
    );
    assert_eq!(png_size(&d.join("b.png")), (900, 2 * 260));
    ok(
        d,
        &[
            "plot", "b.mcap", "--kind", "hybrid", "--vars", "h", "-o", "B.PNG",
        ],
    );
    assert_eq!(png_size(&d.join("B.PNG")), (900, 460));
    // An extension that is no image format: exit 2 before anything runs.
    let out = hybsim(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "--no-mcap",
            "--plot",
            "b.pdf",
        ],
    );
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("`.pdf`"), "{}", stderr(&out));
    let out = hybsim(d, &["plot", "b.mcap", "-o", "b.jpg"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(!d.join("b.jpg").exists() && !d.join("b.pdf").exists());
}

/// Truncated, empty, foreign and non-MCAP files, unknown names and kinds
/// that cannot draw the selection: a clear error and exit 2, no image.
#[test]
fn unreadable_files_and_unknown_names_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    ok(d, &["run", ball.to_str().unwrap(), "-q", "-o", "b.mcap"]);
    let bytes = std::fs::read(d.join("b.mcap")).unwrap();
    std::fs::write(d.join("cut.mcap"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(d.join("empty.mcap"), b"").unwrap();
    std::fs::write(d.join("text.mcap"), b"t,j\n0,0\n").unwrap();
    // An MCAP file that is not a hybsim run.
    {
        let file = std::io::BufWriter::new(std::fs::File::create(d.join("foreign.mcap")).unwrap());
        let mut w = mcap::Writer::new(file).unwrap();
        w.finish().unwrap();
    }
    for (file, says) in [
        ("cut.mcap", "cut short"),
        ("empty.mcap", "not an MCAP file"),
        ("text.mcap", "not an MCAP file"),
        ("foreign.mcap", "not a hybsim run"),
        ("missing.mcap", "cannot read"),
    ] {
        let out = hybsim(d, &["plot", file, "-o", "x.svg"]);
        assert_eq!(code(&out), 2, "{file}: {}", stderr(&out));
        assert!(stderr(&out).contains(says), "{file}: {}", stderr(&out));
        assert!(!stderr(&out).contains("panicked"), "{}", stderr(&out));
    }
    // A damaged chunk is refused by its CRC: a byte changed in the compressed
    // data often still decompresses, into other numbers (those were plotted).
    let chunk = mcap::read::Summary::read(&bytes)
        .unwrap()
        .unwrap()
        .chunk_indexes[0]
        .clone();
    let (start, len) = (
        chunk.chunk_start_offset as usize,
        chunk.chunk_length as usize,
    );
    for k in 0..24 {
        let mut damaged = bytes.clone();
        damaged[start + len / 4 + k * (len / 2) / 24] ^= 0x5a;
        std::fs::write(d.join("damaged.mcap"), &damaged).unwrap();
        let out = hybsim(d, &["plot", "damaged.mcap", "-o", "x.svg"]);
        assert_eq!(code(&out), 2, "byte {k}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("cannot be read back"),
            "{}",
            stderr(&out)
        );
    }
    let out = hybsim(d, &["plot", "b.mcap", "--vars", "h,nope", "-o", "x.svg"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("`--vars nope`"), "{}", stderr(&out));
    let out = hybsim(
        d,
        &[
            "plot", "b.mcap", "--kind", "phase", "--vars", "h", "-o", "x.svg",
        ],
    );
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("two components"), "{}", stderr(&out));
    // The input itself is never the output.
    let out = hybsim(d, &["plot", "b.mcap", "-o", "b.mcap"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(!d.join("x.svg").exists());
    assert_eq!(std::fs::read(d.join("b.mcap")).unwrap(), bytes);
    // A state left out of the log is not in the file: named as unknown.
    ok(
        d,
        &[
            "run",
            ball.to_str().unwrap(),
            "-q",
            "-o",
            "h.mcap",
            "--log-vars",
            "h",
        ],
    );
    let out = hybsim(d, &["plot", "h.mcap", "--vars", "v"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("known: h;"), "{}", stderr(&out));
    // The default image is the file's name with .svg.
    ok(d, &["plot", "h.mcap"]);
    assert!(d.join("h.svg").exists());
}

/// A file that logged outputs only draws them by default; one that logged
/// neither states nor outputs draws only its domain: any other kind is a
/// usage error, not a blank image.
#[test]
fn a_log_without_states_plots_its_outputs_or_refuses_an_empty_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    let ball = ball.to_str().unwrap();
    ok(
        d,
        &["run", ball, "-q", "-o", "e.mcap", "--log-vars", "energy"],
    );
    ok(d, &["plot", "e.mcap", "-o", "e.svg"]);
    let svg = std::fs::read_to_string(d.join("e.svg")).unwrap();
    assert!(texts(&svg).iter().any(|t| t.contains("energy")), "{svg}");
    ok(d, &["run", ball, "-q", "-o", "n.mcap", "--log-vars", ""]);
    for kind in ["flows", "jumps", "hybrid"] {
        let out = hybsim(d, &["plot", "n.mcap", "--kind", kind, "-o", "n.svg"]);
        assert_eq!(code(&out), 2, "{kind}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("needs a component, 0 selected")
                && stderr(&out).contains("logged no state or output"),
            "{kind}: {}",
            stderr(&out)
        );
        assert!(!d.join("n.svg").exists());
    }
    ok(d, &["plot", "n.mcap", "--kind", "domain", "-o", "n.svg"]);
}

/// Every shipped model's file reads back (every layout shape: matrices,
/// families of vectors and matrices, subsystem instances, outputs) and
/// draws, as flows and in 3-D; the values read back are those of the CSV
/// of the same run, bit for bit.
#[test]
fn every_shipped_model_plots_from_its_file() {
    use hybsim::sinks::mcap_read::RunLog;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for m in super::outputs::shipped_models() {
        let name = m.file_stem().unwrap().to_string_lossy().into_owned();
        let mcap = format!("{name}.mcap");
        let csv = d.join(format!("{name}.csv"));
        let bytes = super::outputs::short_run(d, &m, &mcap, &["--csv", csv.to_str().unwrap()]);
        for kind in ["flows", "hybrid"] {
            let out = format!("{name}-{kind}.svg");
            ok(d, &["plot", &mcap, "--kind", kind, "-o", &out]);
            let svg = std::fs::read_to_string(d.join(&out)).unwrap();
            assert!(svg.contains("<polyline"), "{name} {kind}: nothing drawn");
        }
        // The samples read back equal the CSV's rows (states, then outputs).
        let log = RunLog::read(&bytes).unwrap();
        let states = log.info.state_layout.components();
        let outputs = log.info.output_layout.components();
        let mut rows = csv::Reader::from_path(&csv).unwrap();
        let mut read = 0;
        log.replay(&bytes, |at, _, x, y| {
            let row = rows
                .records()
                .next()
                .unwrap_or_else(|| panic!("{name}: more samples than CSV rows"))
                .unwrap();
            let cell = |k: usize| row[k].parse::<f64>().unwrap().to_bits();
            assert_eq!(cell(0), at.t.to_bits(), "{name}: t");
            assert_eq!(row[1].parse::<u64>().unwrap(), at.j, "{name}: j");
            let values = states
                .iter()
                .map(|&(k, _)| x[k])
                .chain(outputs.iter().map(|&(k, _)| y[k]));
            for (c, v) in values.enumerate() {
                assert_eq!(cell(3 + c), v.to_bits(), "{name}: column {}", 3 + c);
            }
            read += 1;
        })
        .unwrap();
        assert!(
            read >= 2 && rows.records().next().is_none(),
            "{name}: {read} samples"
        );
    }
}

/// Every byte of a run's chunk flipped in turn: reading the run back is a
/// `Damaged` error or the run itself, never an abort. The mcap reader
/// reserved what damaged LZ4 data claimed (one flip asked for 3·10¹⁸ bytes
/// and aborted the process); chunks are now checked against their declared
/// size and CRC first. The opcode too: the reader skipped a record whose
/// opcode is not a chunk's, losing its samples without an error.
#[test]
fn every_damaged_chunk_byte_is_an_error_not_an_abort() {
    use hybsim::sinks::mcap_read::RunLog;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    ok(d, &["run", ball.to_str().unwrap(), "-q", "-o", "b.mcap"]);
    let bytes = std::fs::read(d.join("b.mcap")).unwrap();
    let chunk = mcap::read::Summary::read(&bytes)
        .unwrap()
        .unwrap()
        .chunk_indexes[0]
        .clone();
    let start = chunk.chunk_start_offset as usize;
    let mut refused = 0;
    for pos in start..start + chunk.chunk_length as usize {
        let mut damaged = bytes.clone();
        damaged[pos] ^= 0x5a;
        let read = RunLog::read(&damaged).and_then(|log| log.replay(&damaged, |_, _, _, _| {}));
        assert!(
            pos != start || read.is_err(),
            "a flipped opcode is read as the run"
        );
        refused += usize::from(read.is_err());
    }
    // A flip in the chunk's data or CRC cannot go unnoticed.
    assert!(
        refused * 10 >= (chunk.chunk_length as usize) * 9,
        "{refused} of {}",
        chunk.chunk_length
    );
}

/// A damaged chunk is an error of `hybsim info` as of `hybsim plot` (exit
/// 2), whatever byte is hit: its data (the summary alone passed `info`),
/// its opcode (the reader skipped a record that is not a chunk: `plot`
/// drew the run without that chunk's samples, exit 0), or its header
/// fields.
#[test]
fn info_and_plot_refuse_a_damaged_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ball = model("bouncing_ball.hyb");
    ok(d, &["run", ball.to_str().unwrap(), "-q", "-o", "b.mcap"]);
    ok(d, &["info", "b.mcap"]);
    let bytes = std::fs::read(d.join("b.mcap")).unwrap();
    let chunk = mcap::read::Summary::read(&bytes)
        .unwrap()
        .unwrap()
        .chunk_indexes[0]
        .clone();
    let start = chunk.chunk_start_offset as usize;
    let len = chunk.chunk_length as usize;
    // Opcode, record length, uncompressed size, compression name, data.
    for (what, pos) in [
        ("opcode", start),
        ("length", start + 1),
        ("size", start + 25),
        ("compression", start + 41),
        ("data", start + len / 2),
    ] {
        let mut damaged = bytes.clone();
        damaged[pos] ^= 0x5a;
        std::fs::write(d.join("damaged.mcap"), &damaged).unwrap();
        for args in [
            &["info", "damaged.mcap"][..],
            &["info", "--json", "damaged.mcap"],
            &["plot", "damaged.mcap", "-o", "x.svg"],
        ] {
            let out = hybsim(d, args);
            assert_eq!(code(&out), 2, "{what}, {args:?}: {}", stderr(&out));
            assert!(
                stderr(&out).contains("cannot be read back"),
                "{what}, {args:?}: {}",
                stderr(&out)
            );
        }
    }
}
