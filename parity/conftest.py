"""Parity fixtures: where the reference cases are, one test parameter per case.

The folder is ``--parity-dir``, else ``$GNS_PARITY_DIR``, else ``<repo>/../shared/parity``.
Without cases there, fixture-based tests skip with the reason, except under CI
(``$CI`` set), where missing fixtures are a failure: parity must run there.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from .cases import ENV_VAR, ReferenceCase, find_case_files, load_case, parity_dir


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("parity")
    group.addoption("--parity-dir", help=f"folder of reference cases (default: ${ENV_VAR} or <repo>/../shared/parity)")
    group.addoption("--parity-report", action="store_true", help="print every measured parity deviation")


def _folder(config: pytest.Config) -> Path:
    return parity_dir(config.getoption("--parity-dir"))


def pytest_report_header(config: pytest.Config) -> str:
    folder = _folder(config)
    cases = [p.stem for p in find_case_files(folder)]
    return f"parity fixtures: {folder} ({', '.join(cases) if cases else 'no cases found'})"


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "case_path" in metafunc.fixturenames:
        paths = find_case_files(_folder(metafunc.config))
        params = [pytest.param(p, id=p.stem) for p in paths] or [pytest.param(None, id="no-cases")]
        metafunc.parametrize("case_path", params)


def _require_cases(config: pytest.Config) -> None:
    folder = _folder(config)
    reason = (
        f"no parity cases in {folder} (a *.npz with a meta/json member); "
        f"point --parity-dir or ${ENV_VAR} at the reference fixtures"
    )
    if os.environ.get("CI"):
        pytest.fail(f"{reason}; CI is set, so parity must run", pytrace=False)
    pytest.skip(reason)


@pytest.fixture
def reference_case(case_path: Path | None, request: pytest.FixtureRequest) -> ReferenceCase:
    if case_path is None:
        _require_cases(request.config)
    return load_case(case_path)


@pytest.fixture
def smallest_case(request: pytest.FixtureRequest) -> ReferenceCase:
    """The case with the fewest particles (mutation tests only need one that can fail)."""
    paths = find_case_files(_folder(request.config))
    if not paths:
        _require_cases(request.config)
    return min((load_case(p) for p in paths), key=lambda c: c.arrays["input/particle_type"].shape[0])


@pytest.fixture(scope="package", autouse=True)
def one_torch_thread():
    """Run parity on one intra-op thread.

    On a shared machine, OpenMP workers spin while other jobs hold the cores and a
    forward pass gets ~20x slower. Forward passes are bit-identical with 1 and 2
    threads (fixture README); gradients differ ~1e-5 relative, far inside tolerance.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


_REPORT: list[tuple[str, str]] = []


@pytest.fixture
def record_deviations():
    """Keep measured deviations for ``--parity-report``."""

    def record(case: str, deviations) -> None:
        _REPORT.extend((case, str(d)) for d in deviations)

    return record


def pytest_terminal_summary(terminalreporter, config: pytest.Config) -> None:
    if config.getoption("--parity-report") and _REPORT:
        terminalreporter.section("parity deviations (measured vs tolerance)")
        for case, line in _REPORT:
            terminalreporter.write_line(f"{case}: {line}")
