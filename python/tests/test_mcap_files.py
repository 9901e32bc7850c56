"""`hybsim info` and `hybsim plot` on MCAP files written by another tool (the
official Python `mcap` writer): foreign files, many channels, and hybsim runs
whose `run.json` was damaged. Each is an error with exit code 2, never a
crash."""

import json
import subprocess

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer


def rewrite(src, dst, edit):
    """Copies the hybsim run `src` to `dst` record by record with the
    official writer, `edit` applied to its `run.json`."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
        attachments = list(reader.iter_attachments())
        messages = list(reader.iter_messages(log_time_order=False))
    with open(dst, "wb") as f:
        w = Writer(f)
        w.start("", "another tool")
        for m in metadata:
            w.add_metadata(m.name, m.metadata)
        for a in attachments:
            data = a.data
            if a.name == "run.json":
                run = json.loads(data)
                edit(run)
                data = json.dumps(run).encode()
            w.add_attachment(a.log_time, a.create_time, a.name, a.media_type, data)
        schemas = {
            sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()
        }
        channels = {
            cid: w.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], c.metadata)
            for cid, c in summary.channels.items()
        }
        for _, channel, msg in messages:
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        w.finish()


def hybsim(bin, *args):
    return subprocess.run([str(bin), *map(str, args)], capture_output=True, text=True)


@pytest.fixture
def run_file(hybsim_bin, models, tmp_path):
    path = tmp_path / "ball.mcap"
    out = hybsim(hybsim_bin, "run", models / "bouncing_ball.hyb", "-q", "-o", path)
    assert out.returncode == 0, out.stderr
    return path


def test_a_run_copied_by_another_writer_reads_back(hybsim_bin, run_file, tmp_path):
    copy = tmp_path / "copy.mcap"
    rewrite(run_file, copy, lambda run: None)
    for args in (["info", copy], ["plot", copy, "-o", tmp_path / "copy.svg"]):
        out = hybsim(hybsim_bin, *args)
        assert out.returncode == 0, out.stderr


def set_dim(what, dim):
    def edit(run):
        run[what]["dim"] = dim

    return edit


def set_offset(offset):
    def edit(run):
        run["state"]["layout"]["entries"][1]["Field"]["offset"] = offset

    return edit


@pytest.mark.parametrize(
    "edit, says",
    [
        # Vectors of 10^13 numbers aborted the process ("memory allocation of
        # 80000000000000 bytes failed").
        (set_dim("state", 10**13), "does not fit in memory"),
        (set_dim("outputs", 10**13), "does not fit in memory"),
        (set_dim("state", -1), "not a count"),
        # An offset that overflowed the layout check's sum.
        (set_offset(2**64 - 1), "spans components"),
    ],
)
def test_a_damaged_run_description_is_an_error(hybsim_bin, run_file, tmp_path, edit, says):
    damaged = tmp_path / "damaged.mcap"
    rewrite(run_file, damaged, edit)
    out = hybsim(hybsim_bin, "plot", damaged, "-o", tmp_path / "d.svg")
    assert out.returncode == 2, out.stderr
    assert says in out.stderr, out.stderr
    assert "panicked" not in out.stderr and "memory allocation" not in out.stderr
    assert not (tmp_path / "d.svg").exists()


def test_foreign_files_and_many_channels_are_errors(hybsim_bin, tmp_path):
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start("x", "another tool")
        schema = w.register_schema("S", "jsonschema", b'{"type": "object"}')
        # The most channels MCAP can number (u16 ids).
        for k in range(65535):
            channel = w.register_channel(f"/t{k}", "json", schema)
            if k < 100:
                w.add_message(channel, k, b'{"a": 1}', k)
        w.finish()
    for args in (["info", path], ["plot", path, "-o", tmp_path / "f.svg"]):
        out = hybsim(hybsim_bin, *args)
        assert out.returncode == 2, out.stderr
        assert "not a hybsim run" in out.stderr, out.stderr
