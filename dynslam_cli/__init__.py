"""dynslam: 2D laser SLAM in dynamic environments (Wolf & Sukhatme 2005) over recorded logs."""

__version__ = "0.1.0"


def run() -> None:
    """The ``dynslam`` command. Defined here, where importing costs nothing, so a Ctrl-C
    while the command line module still loads ends as one later would: exit 130, one line."""
    import sys

    try:
        from dynslam_cli.cli import entry
    except KeyboardInterrupt:
        sys.stderr.write("dynslam: interrupted; no output written\n")
        sys.exit(130)
    entry()
