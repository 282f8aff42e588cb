"""What a wrong input is told: one line naming the file or argument and the problem, exit status 2, in words
that say what the input is (a folder, a text file, a cut file), never a traceback nor a message cut short;
an unphysical camera refused where every camera is built; no secret of a stream URL printed or recorded."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from test_faults import one_line

from layouts import Intrinsics
from layouts.errors import InputError
from mvracklay.cli import main

QUIET = ["--quiet", "--no-rrd", "--threads", "1"]


@pytest.fixture(scope="module")
def seq(tiny_dataset: Path) -> Path:
    return tiny_dataset / "seq_00000"


# --- cameras ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "fields, problem",
    [
        ({"fx": 1e308}, "fx = 1e+308 gives a horizontal field of view of 0 deg"),
        ({"fy": 1e308}, "fy = 1e+308 gives a vertical field of view of 0 deg"),
        ({"fx": 1e-300}, "fx = 1e-300 gives a horizontal field of view of 180 deg"),
        ({"cx": 1e308}, "cx = 1e+308 is outside the image (128 pixels wide)"),
        ({"cy": -3.0}, "cy = -3 is outside the image (128 pixels high)"),
    ],
)
def test_an_unphysical_camera_file_is_one_line(seq, tiny_checkpoint, tmp_path, capsys, fields, problem):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 110.0, "fy": 110.0, "cx": 64.0, "cy": 64.0, **fields}))
    argv = ["--out", str(tmp_path / "o"), "--camera", str(cam), "--checkpoint", str(tiny_checkpoint), "--quiet"]
    one_line(capsys, main(["run", str(seq), *argv, "--no-rrd"]), "run", f"--camera {cam}: {problem}")
    one_line(capsys, main(["predict", str(seq), *argv]), "predict", f"--camera {cam}: {problem}")
    assert not (tmp_path / "o").exists()


def test_an_unphysical_inline_camera_and_meta_json_are_one_line(seq, tiny_checkpoint, tmp_path, capsys):
    out = ["--out", str(tmp_path / "o"), "--checkpoint", str(tiny_checkpoint), "--quiet"]
    rc = main(["predict", str(seq), *out, "--camera", "1e308,1e308,64,64"])
    one_line(capsys, rc, "predict", "--camera 1e308,1e308,64,64: fx = 1e+308 gives a horizontal field of view")
    bad = tmp_path / "seq"
    shutil.copytree(seq, bad)
    meta = json.loads((bad / "meta.json").read_text())
    meta["intrinsics"]["fy"] = 1e308
    (bad / "meta.json").write_text(json.dumps(meta))
    before = (bad / "meta.json").read_bytes()
    one_line(capsys, main(["run", str(bad), *out, "--no-rrd"]), "run", f"{bad / 'meta.json'}: fy = 1e+308 gives")
    assert (bad / "meta.json").read_bytes() == before and not (tmp_path / "o").exists()


def test_intrinsics_refuse_unphysical_values_wherever_they_are_built():
    with pytest.raises(InputError, match=r"^fx = 1e\+308 gives a horizontal field of view of 0 deg .*\[0.1, 179\]"):
        Intrinsics(1e308, 1e308, 32.0, 32.0, 64, 64)
    with pytest.raises(InputError, match=r"^ckpt \(intrinsics\): cx = 65 is outside the image \(64 pixels wide\)$"):
        Intrinsics.from_dict(
            {"fx": 50.0, "fy": 50.0, "cx": 65.0, "cy": 32.0, "width": 64, "height": 64}, "ckpt (intrinsics)"
        )
    assert Intrinsics.from_fov(64, 64, 170.0).hfov_deg == pytest.approx(170.0)  # the generator's widest
    assert Intrinsics(20000.0, 20000.0, 32.0, 32.0, 64, 64).hfov_deg > 0.1  # a long telephoto is a camera


# --- words -----------------------------------------------------------------------------------------------------
def _folder(p: Path, good: Path) -> None:
    p.mkdir()


def _text(p: Path, good: Path) -> None:
    p.write_text("hello, this is not a model\n")


def _cut(p: Path, good: Path) -> None:
    p.write_bytes(good.read_bytes()[: good.stat().st_size // 2])


def _empty(p: Path, good: Path) -> None:
    p.write_bytes(b"")


@pytest.mark.parametrize(
    "make, said",
    [
        (_folder, "is a folder, not a checkpoint file"),
        (_text, "not a checkpoint: not a PyTorch archive"),
        (_cut, "truncated or corrupted checkpoint (PytorchStreamReader failed reading zip archive: failed finding"),
        (_empty, "an empty file, not a checkpoint"),
    ],
    ids=["folder", "text", "truncated", "empty"],
)
@pytest.mark.parametrize("command", ["run", "predict", "evaluate"])
def test_a_checkpoint_that_is_none_is_said_as_such(seq, tiny_checkpoint, tmp_path, capsys, make, said, command):
    ckpt = tmp_path / "model.pt"
    make(ckpt, tiny_checkpoint)
    out = ["--out", str(tmp_path / "o")] if command != "evaluate" else ["--data", str(seq.parent), "--split", "all"]
    argv = [command, *([str(seq)] if command != "evaluate" else []), *out, "--checkpoint", str(ckpt), "--quiet"]
    line = one_line(capsys, main(argv), command, f"{ckpt}: ", said)
    assert line.endswith((said, ")"))  # whole words, never a message cut mid-sentence
    assert "KeyError" not in line and "file not found" not in line and not (tmp_path / "o").exists()


def test_a_text_or_misnamed_npz_is_said_as_such(seq, tmp_path, capsys):
    import numpy as np

    from layouts.fileio import load_npy, load_npz

    bad = tmp_path / "seq"
    shutil.copytree(seq, bad)
    layout = bad / "layouts" / "000001.npz"
    layout.write_text("top,front\n1,2\n")
    rc = main(["reconstruct", str(bad), "--out", str(tmp_path / "o"), "--quiet", "--no-rrd"])
    one_line(capsys, rc, "reconstruct", f"{layout}: not a .npz archive (its first bytes are no NumPy format's)")
    assert not (tmp_path / "o").exists()
    np.save(tmp_path / "a.npy", np.zeros(3))
    for path, load, said in [
        (tmp_path / "a.npy", load_npz, "expected a .npz archive, found a .npy array"),  # was a TypeError
        (tmp_path, load_npz, "is a folder, not a .npz archive"),
        (layout, load_npy, "not a .npy array"),
    ]:
        with pytest.raises(InputError, match="^" + str(path) + ": " + said.replace(".", r"\.")):
            load(path)


# --- a secret in a stream URL ----------------------------------------------------------------------------------
def test_a_url_shows_no_secret():
    from mvracklay.live_source import shown

    assert shown("rtsp://admin:s3cr@t@10.0.0.5:554/live?fps=5") == "rtsp://10.0.0.5:554/live?fps=5"
    assert (
        shown("http://h/x?user=cam&PassWord=a;api-key=b&client_secret=c&keyframes=1&Signature=d#access_token=e&s=1")
        == "http://h/x?user=cam&PassWord=***;api-key=***&client_secret=***&keyframes=1&Signature=***#access_token=***&s=1"
    )
    for name in ("password", "token", "key", "secret", "auth", "access_token", "sig", "signature", "api_key", "apikey",
                 "pass", "pwd", "TOKEN", "X-Amz-Signature", "pass%77ord"):  # fmt: skip
        assert shown(f"srt://h:9000?mode=caller&{name}=hunter2") == f"srt://h:9000?mode=caller&{name}=***", name
    assert shown("udp://127.0.0.1:5000?pkt_size=1316") == "udp://127.0.0.1:5000?pkt_size=1316"


def _mpegts(frames: list) -> bytes:
    import io

    import av

    buf = io.BytesIO()
    with av.open(buf, "w", format="mpegts") as out:
        stream = out.add_stream("mpeg2video", rate=10)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        for rgb in frames:
            out.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        out.mux(stream.encode())
    return buf.getvalue()


def test_a_password_in_a_stream_url_is_neither_printed_nor_recorded(seq, tiny_checkpoint, tmp_path, capsys):
    import socket
    import threading
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    import numpy as np
    from PIL import Image

    body = _mpegts([np.asarray(Image.open(p).convert("RGB")) for p in sorted((seq / "rgb").glob("*.png"))[:6]])

    class Clip(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - the stream, whatever the query
            self.send_response(200)
            self.send_header("Content-Type", "video/mp2t")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Clip)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    port = server.server_address[1]
    secret = "?user=cam&password=hunter2&Token=t0k3n&fps=10"
    url = f"http://viewer:pa55@127.0.0.1:{port}/live.ts{secret}"
    out = tmp_path / "o"
    try:
        rc = main(["run", url, "--out", str(out), "--checkpoint", str(tiny_checkpoint), *QUIET])
    finally:
        server.shutdown()
        server.server_close()
    said = capsys.readouterr()
    assert rc == 0, said.err
    meta = json.loads((out / "warehouse.json").read_text())["meta"]
    assert meta["input"] == f"http://127.0.0.1:{port}/live.ts?user=cam&password=***&Token=***&fps=10"
    for text in [said.out, said.err, *(p.read_bytes().decode("latin-1") for p in out.rglob("*") if p.is_file())]:
        assert "hunter2" not in text and "t0k3n" not in text and "pa55" not in text
    with socket.socket() as s:  # a port nothing listens on: the failure names the URL without its secrets
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    rc = main(["run", f"tcp://127.0.0.1:{closed}{secret}", "--out", str(tmp_path / "o2"), "--checkpoint",
               str(tiny_checkpoint), *QUIET])  # fmt: skip
    line = one_line(capsys, rc, "run", f"tcp://127.0.0.1:{closed}?user=cam&password=***&Token=***&fps=10: ")
    assert "hunter2" not in line and "t0k3n" not in line
