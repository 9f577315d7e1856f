"""``apmcal ui``: the whole tool in the browser — logs, a live vehicle, a fleet — served on this
computer only (:mod:`apmcal.ui`)."""
from __future__ import annotations

from apmcal.cli.common import number_type


def add_parser(sub) -> None:
    """The ``ui`` sub-command and its options."""
    ui = sub.add_parser(
        "ui", help="the whole tool in your web browser (logs, a live vehicle, a fleet)",
        description="Start apmcal's page on this computer and open it in the default browser. "
                    "It listens on 127.0.0.1 only, and answers only the address printed (it "
                    "carries a random access token). Ctrl-C stops it; an upload under way "
                    "ends first.")
    ui.add_argument("--port", type=number_type(int, 1, 65535, what="a port"), default=None,
                    help="the port (default: the first free one from 8347 on)")
    ui.add_argument("--no-browser", action="store_true",
                    help="only print the address; open it yourself")


def run(args) -> int:
    """``apmcal ui``: serve the page until Ctrl-C; exit status."""
    from apmcal.ui.server import serve

    return serve(args.port, not args.no_browser, say=lambda text: print(text, flush=True))
