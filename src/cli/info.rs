//! `hybsim info`: what a run's MCAP file holds (model, parameters, seed,
//! solver, horizons, channels and message counts, how the run ended) and
//! the command that reproduces it.

use std::path::PathBuf;

use clap::Args;
use hybsim::sinks::mcap_read::{RunSummary, check_chunks};

use super::{EXIT_MODEL_ERROR, EXIT_OK, shell_word};

/// Arguments of `hybsim info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The MCAP file of a run.
    pub file: PathBuf,
    /// Print everything as one JSON object (metadata, channels, attachments).
    #[arg(long)]
    pub json: bool,
}

/// `hybsim info`. An unreadable, truncated, foreign or non-MCAP file, or
/// one with a damaged chunk (checked as `hybsim plot` checks them), is an
/// error with exit code 2.
pub fn execute(args: InfoArgs) -> anyhow::Result<u8> {
    let bytes = match super::read_mcap_input(&args.file) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("error: cannot read `{}`: {e}", args.file.display());
            return Ok(EXIT_MODEL_ERROR);
        }
    };
    // The summary alone would pass a file whose data `hybsim plot` refuses.
    let read = RunSummary::read(&bytes).and_then(|run| Ok((run, check_chunks(&bytes)?)));
    let (run, chunks) = match read {
        Ok(read) => read,
        Err(e) => {
            eprintln!("error: `{}`: {e}", args.file.display());
            return Ok(EXIT_MODEL_ERROR);
        }
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&run.to_json())?);
        return Ok(EXIT_OK);
    }
    let get = |record: &str, key: &str| run.get(record, key).unwrap_or("?").to_string();
    let pairs = |record: &str| -> String {
        run.metadata
            .get(record)
            .map(|m| {
                m.iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_default()
    };
    println!(
        "file        {} ({} bytes)",
        args.file.display(),
        bytes.len()
    );
    println!(
        "model       {} ({}, sha256 {})",
        get("hybsim.run", "model_name"),
        get("hybsim.run", "model"),
        get("hybsim.run", "model_sha256")
    );
    println!("hybsim      {}", get("hybsim.run", "version"));
    println!("seed        {}", get("hybsim.run", "seed"));
    println!("parameters  {}", pairs("hybsim.parameters"));
    println!("solver      {}", pairs("hybsim.solver"));
    if run.metadata.contains_key("hybsim.design") {
        println!("design      {}", pairs("hybsim.design"));
    }
    println!("chunks      {chunks}, each checked (record, size, CRC, message count)");
    println!("channels");
    for c in &run.channels {
        println!(
            "  {:<18} {:>10} messages  {} {}",
            c.topic, c.messages, c.encoding, c.schema
        );
    }
    if run.metadata.contains_key("hybsim.result") {
        println!("result      {}", pairs("hybsim.result"));
    } else {
        println!("result      none (the run did not complete its file)");
    }
    if run.metadata.contains_key("hybsim.metrics") {
        println!("metrics     {}", pairs("hybsim.metrics"));
    }
    let argv = run.argv();
    if argv.is_empty() {
        println!("replay      (written from Rust; no command line recorded)");
    } else {
        let words: Vec<String> = argv.iter().map(|a| shell_word(a)).collect();
        println!("replay      {}", words.join(" "));
    }
    Ok(EXIT_OK)
}
