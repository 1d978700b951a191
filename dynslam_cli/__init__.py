"""dynslam: 2D laser SLAM in dynamic environments (Wolf & Sukhatme 2005) over recorded logs."""

__version__ = "0.1.0"


def run() -> None:
    """The ``dynslam`` command. Defined here, where importing costs nothing, so that a Ctrl-C
    while the tool still loads and reads its arguments (nothing is written yet) ends at once
    as one later would: one line, exit 130. A command's work puts the ordinary handler back
    (its clean-up runs on the exception)."""
    import os
    import signal

    def interrupted(signum: int, frame: object) -> None:
        os.write(2, b"dynslam: interrupted; no output written\n")
        os._exit(130)

    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not if ignored
        signal.signal(signal.SIGINT, interrupted)
    if "OPENBLAS_NUM_THREADS" not in os.environ and "OMP_NUM_THREADS" not in os.environ:
        # numpy's OpenBLAS otherwise runs a thread per core in every call, and small
        # calls in a loop (L-BFGS-B's in the prior's refinement: 20x slower) wait on
        # threads that the read-ahead process (dynslam_cli.readahead) keeps off the core
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from dynslam_cli.cli import main

    main()
