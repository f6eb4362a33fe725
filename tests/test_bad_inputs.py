"""Every case of the bad-input corpus (`scripts/bad_input_corpus.py`) through the CLI, in-process: a clear
refusal (non-zero exit, one line, no traceback, nothing created or changed) or the expected handling.
The fixtures are real: two expert demos of libero_object/0, their annotation, a tiny policy and critic."""

from __future__ import annotations

import os
import shutil
import traceback

import pytest
from conftest import load_benchmark

from elegant.cli import main

pytestmark = pytest.mark.sim
corpus = load_benchmark("bad_input_corpus", folder="scripts")


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    scratch = str(tmp_path_factory.mktemp("corpus"))
    paths = corpus.make_fixtures(scratch)
    backup = str(tmp_path_factory.mktemp("pristine"))
    shutil.copytree(scratch, backup, dirs_exist_ok=True)
    return paths, corpus.snapshot(scratch), backup


def run_in_process(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's refusals
        code = exc.code if isinstance(exc.code, int) else 1
    except Exception:
        return 1, traceback.format_exc()
    return code, capsys.readouterr().err


@pytest.mark.parametrize("case", corpus.CASES, ids=[c.name for c in corpus.CASES])
def test_each_bad_input_is_refused_in_one_line_or_handled(case, fixtures, capsys):
    paths, pristine, backup = fixtures
    scratch = paths["s"]
    if corpus.snapshot(scratch) != pristine:  # an earlier case's output
        shutil.rmtree(scratch)
        shutil.copytree(backup, scratch)
    capsys.readouterr()
    before = corpus.snapshot(scratch)
    code, stderr = run_in_process(corpus.argv_of(case, paths), capsys)
    verdict = corpus.classify(case, code, stderr, before, corpus.snapshot(scratch))
    assert verdict == ("clear" if case.expect == corpus.REFUSE else "handled"), (
        f"{case.name}: {verdict}, exit {code}: {stderr[-800:]}; "
        f"created or changed: {sorted(set(corpus.snapshot(scratch).items()) ^ set(before.items()))[:5]}"
    )
    assert not any(os.path.exists(os.path.join(scratch, name)) for name in ("t.hdf5.lock", "e.lock"))
