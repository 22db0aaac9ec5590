"""io/pipe_sink.py: what a writer puts through the pipe path lands in the file byte for byte,
in order; a file that refuses (ENOSPC) is reported once by close() while the writer is never
left blocked; a real Rerun file sink through it gives a recording Rerun reads back."""

from __future__ import annotations

import errno
import io
import os
import threading

import numpy as np
import pytest
import rerun as rr

from seg2pose.io.pipe_sink import CHUNK, PipeSink


def _write_through(path: str, blocks: list[bytes]) -> None:
    with open(path, "wb") as w:  # as a library does: its own open of the path
        for b in blocks:
            w.write(b)


def test_bytes_arrive_whole_and_in_order():
    rng = np.random.default_rng(0)
    blocks = [rng.bytes(int(n)) for n in rng.integers(1, 3 * CHUNK, 12)]
    f = io.BytesIO()
    sink = PipeSink(f)
    _write_through(sink.path, blocks)
    sink.close()
    assert f.getvalue() == b"".join(blocks)


class _FullAfter(io.RawIOBase):
    """A file with room for ``room`` bytes; then ENOSPC, as a full disk."""

    def __init__(self, room: int) -> None:
        self.room, self.got = room, 0

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        if self.got + len(b) > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.got += len(b)
        return len(b)


def test_a_full_file_is_reported_and_the_writer_never_waits():
    f = _FullAfter(room=CHUNK // 2)
    sink = PipeSink(f)
    done = threading.Event()

    def writer():  # 20 pipes' worth after the file is full: blocks unless the rest is drained
        _write_through(sink.path, [b"x" * CHUNK] * 20)
        done.set()

    t = threading.Thread(target=writer, daemon=True)
    t.start()
    assert done.wait(30), "the writer was left waiting on a full pipe"
    t.join()
    with pytest.raises(OSError) as e:
        sink.close()
    assert e.value.errno == errno.ENOSPC
    assert f.got <= CHUNK // 2


def test_close_without_a_writer_returns():
    f = io.BytesIO()
    PipeSink(f).close()
    assert f.getvalue() == b""


def test_a_rerun_file_sink_through_the_pipe_reads_back(tmp_path):
    out = tmp_path / "r.rrd"
    rec = rr.RecordingStream("s2p-test", recording_id="pipe")
    with open(out, "wb") as f:
        sink = PipeSink(f)
        rec.set_sinks(rr.FileSink(sink.path))
        for i in range(30):
            rec.set_time("frame", sequence=i)
            rec.log("p", rr.Points3D(np.full((5, 3), float(i))))
        rec.flush()
        rec.disconnect()
        sink.close()
    import rerun.chunk as rc

    rows = sum(ch.num_rows for ch in rc.RrdReader(out).stream()
               if not ch.is_static and ch.entity_path == "/p")
    assert rows == 30
