"""Helpers shared by the tests that drive ``cli.py`` in this process."""

import cli


def run_main(*argv) -> int:
    """``cli.main`` on the arguments (as strings); an argparse error's exit status is returned."""
    try:
        return cli.main([str(a) for a in argv])
    except SystemExit as exc:  # argparse errors exit
        return exc.code
