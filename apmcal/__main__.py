"""``python -m apmcal``: the command line (:func:`apmcal.cli.entry`)."""
import sys

if __name__ == "__main__":       # not when a worker process imports it (multiprocessing, spawn)
    try:
        from apmcal.cli import entry
    except KeyboardInterrupt:    # Ctrl-C before the command line's own handler is in place
        print("apmcal: interrupted (Ctrl-C)", file=sys.stderr)
        sys.exit(130)            # 128 + SIGINT, as cli.EXIT_INTERRUPTED

    entry()
