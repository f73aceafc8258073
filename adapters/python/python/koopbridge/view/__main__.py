"""``python -m koopbridge.view``: watch a koopbridge session live in Rerun (desktop or web viewer),
record it into an ``.rrd``, or open a recorded one (``--open``)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import rerun as rr

from ..serve_args import add_lifeline_argument, add_zenoh_arguments
from .live import Sinks, follow, open_session


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m koopbridge.view",
        description="Watch a koopbridge session in Rerun: every state against its reference, the inputs, the MPC's "
        "solve time and plan, collection and training progress (PROTOCOL.md §10). `koopbridge run --view` starts it.",
        epilog="Examples:\n  python -m koopbridge.view --session demo --connect tcp/127.0.0.1:7501 --web\n"
        "  python -m koopbridge.view --open results/damped-pendulum/view.rrd",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--open", metavar="FILE", help="open a recorded view (.rrd) in Rerun's viewer instead of following a session")
    g = add_zenoh_arguments(p, id_default="view", id_help="viewer id: liveliness token koopbridge/{session}/alive/viewer/{id}")
    g.add_argument("--save", metavar="FILE", help="record what is shown into FILE (.rrd; written as FILE.part until complete)")
    g.add_argument("--web", action="store_true", help="Rerun's web viewer on local ports (its address is printed and written to view.json beside --save)")
    g.add_argument("--native", action="store_true", help="Rerun's desktop viewer (needs a display)")
    g.add_argument("--web-port", type=int, metavar="PORT", help="the web viewer's port (default: a free one)")
    g.add_argument(
        "--video",
        metavar="REFS",
        help="MP4s of these references' loops (comma-separated indices; a [control] loop is 0) for MuJoCo simulators: "
        "the robot beside its reference, rendered offscreen (MUJOCO_GL=egl unless set)",
    )
    g.add_argument("--video-dir", metavar="DIR", help="where the MP4s go (default: videos/ beside --save, else ./videos)")
    add_lifeline_argument(g)
    return p


def open_recording(path: str, web: bool) -> int:
    """Opens a recorded view in Rerun's viewer; a file Rerun cannot read gets Rerun's message."""
    from rerun.chunk import RrdReader

    if not Path(path).is_file():
        print(f"error: {path}: no such file", file=sys.stderr)
        return 2
    try:
        RrdReader(path).recordings()
    except Exception as e:  # noqa: BLE001 - Rerun's own error, passed on
        print(f"error: {path} is not a Rerun recording Rerun can read: {e}", file=sys.stderr)
        return 2
    cmd = [sys.executable, "-m", "rerun", *(["--web-viewer"] if web else []), path]
    return subprocess.call(cmd)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.open:
        return open_recording(args.open, args.web)
    if not (args.save or args.web or args.native):
        args.native = True
    video = None
    if args.video:
        from .video import VideoWriter, parse_episodes

        try:
            episodes = parse_episodes(args.video)
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is imported
        folder = Path(args.video_dir) if args.video_dir else (Path(args.save).parent / "videos" if args.save else Path("videos"))
        video = VideoWriter(folder, episodes)
    rec = rr.RecordingStream("koopbridge", recording_id=args.session)
    sinks = Sinks(args.save, args.web, args.native, args.web_port)
    try:
        sinks.attach(rec)
    except Exception as e:  # noqa: BLE001 - named, then the viewer ends
        print(f"error: Rerun's viewer could not start: {e}", file=sys.stderr)
        return 3
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if args.stdin_lifeline:
        from ..serve_args import start_lifeline

        class _Stopper:
            def stop(self) -> None:
                stop.set()

        start_lifeline(_Stopper(), args)
    s = open_session(args.connect, args.listen, args.mode, args.zenoh_config)

    def ready() -> None:
        if sinks.url:
            print(f"koopbridge view: live at {sinks.url}", file=sys.stderr, flush=True)
        if args.save:
            meta = Path(args.save).with_name("view.json")
            tmp = meta.with_name(meta.name + ".part")
            tmp.write_text(json.dumps({"web": sinks.url, "rrd": str(Path(args.save).resolve())}))
            os.replace(tmp, meta)

    try:
        log = follow(s, args.session, args.id, rec, stop, ready, video)
    except KeyboardInterrupt:
        log = None
    finally:
        sinks.close(rec)
        s.close()
        if video is not None:
            for f in video.close():
                print(f"koopbridge view: video {f}", file=sys.stderr)
    if log is not None:
        import resource

        cpu = resource.getrusage(resource.RUSAGE_SELF)
        print(f"koopbridge view: {log.steps_logged} closed-loop states shown, {cpu.ru_utime + cpu.ru_stime:.1f} s of CPU", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
