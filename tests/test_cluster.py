"""Power analyses on a Dask cluster (two workers on loopback) and power surfaces (--sweep)."""

from __future__ import annotations

import json
import socket
import warnings

import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, write_experiment

# A 2 x 2 study small enough for seconds of simulation on a loaded machine.
SMALL = MINIMAL.replace("""design:""", """  timing:
    sets: coding
    levels:
      fast: {duration_ms: 100, soa_ms: 100}
      slow: {duration_ms: 200, soa_ms: 300}
design:""")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return write_experiment(tmp_path_factory.mktemp("exp"), SMALL, "small.yaml")


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lc = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None)
    try:
        yield lc.scheduler_address.replace("tcp://", "dask://")
    finally:
        lc.close()


def test_the_power_table_on_two_workers_equals_the_one_process_run(cluster, small):
    from vtexp.cluster import connect, threads
    from vtexp.simulate import run_power

    one = run_power(small, 4, 24, seed=3, workers=1)
    client = connect(cluster)
    try:
        assert threads(client) == 2
        on = run_power(small, 4, 24, seed=3, workers=threads(client),
                       executor=client.get_executor())
        # the workers prepared the experiment from its text, checked by SHA-256
        seen = client.run(lambda: sorted(__import__("vtexp.simulate").simulate._SETUPS))
    finally:
        client.close()
    pd.testing.assert_frame_equal(on.table, one.table, check_exact=True)
    pd.testing.assert_frame_equal(on.means, one.means, check_exact=True)
    assert all(len(keys) == 1 for keys in seen.values()) and len(seen) == 2
    assert len(one.table) == 3 and one.table["studies"].min() > 0


def _vtexp(capsys, *args) -> tuple[int, str, str]:
    """``vtexp ARGS`` in this process (the command's own code, without a new interpreter)."""
    from vtexp.cli import main

    capsys.readouterr()
    code = main(list(args))
    got = capsys.readouterr()
    return code, got.out, got.err


def test_a_sweep_on_the_cluster_equals_the_sweep_in_one_process(capsys, cluster, small,
                                                               tmp_path):
    sweep = write_experiment(tmp_path, "participants: [4, 5]\nstudies: 6\n"
                             "repetitions: [1, 2]\n", "sweep.yaml")
    runs = {}
    for name, extra in (("local", ["--workers", "1"]), ("dask", ["--executor", cluster])):
        out = tmp_path / f"{name}.json"
        code, text, err = _vtexp(capsys, "simulate", str(small), "--sweep", str(sweep),
                                 "--seed", "5", "-q", "--out", str(out), *extra)
        assert code == 0, err
        runs[name] = (text, json.loads(out.read_text()))
    (text, local), (text_dask, dask) = runs["local"], runs["dask"]
    assert text == text_dask and local["power"] == dask["power"]
    assert "Power surface (6 studies per point" in text
    assert [ln.split()[:2] for ln in text.splitlines() if ln.strip()[:1].isdigit()] == \
        [["1", "4"], ["1", "5"], ["2", "4"], ["2", "5"]]
    assert len(local["power"]) == 4 * 3 and {p["setting"]["design.repetitions"]
                                             for p in local["points"]} == {1, 2}
    assert len({p["sha256"] for p in local["points"]}) == 2


def test_a_timing_parameter_and_a_csv_surface(capsys, tmp_path):
    sweep = write_experiment(tmp_path, "participants: [4]\nstudies: 4\nvary:\n"
                             "  coding.params.vibration_ms: [150, 200]\n", "sweep.yaml")
    out = tmp_path / "surface.csv"
    code, _, err = _vtexp(capsys, "simulate", str(ROOT / "experiments" / "whirlpool.yaml"),
                          "--sweep", str(sweep), "-q", "--workers", "1", "--out", str(out))
    assert code == 0, err
    t = pd.read_csv(out)
    assert set(t["coding.params.vibration_ms"]) == {150, 200} and (t["participants"] == 4).all()
    assert {"effect", "power", "ci_low", "ci_high", "median_p"} <= set(t.columns)


def test_an_unreachable_scheduler_is_one_message_before_anything_runs(cli, small):
    with socket.socket() as s:              # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = cli("simulate", str(small), "--executor", f"dask://127.0.0.1:{port}", "-q",
            "--connect-timeout", "1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port} within 1 s" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Power" not in r.stdout


def test_scheduler_addresses():
    from vtexp.cluster import scheduler_address
    from vtexp.errors import InputError

    assert scheduler_address("dask://127.0.0.1:8786") == "tcp://127.0.0.1:8786"
    assert scheduler_address("tcp://node-3.lab:8786") == "tcp://node-3.lab:8786"
    for bad in ("dask://nowhere", "dask://host:0", "http://host:8786"):
        with pytest.raises(InputError, match="not a scheduler address"):
            scheduler_address(bad)


def test_a_worker_refuses_a_text_that_does_not_match_its_hash(small):
    from dataclasses import replace

    from vtexp.errors import InputError
    from vtexp.simulate import ExperimentSource

    src = ExperimentSource.of(small)
    with pytest.raises(InputError, match="damaged on the way"):
        replace(src, text=src.text.replace("repetitions: 2", "repetitions: 3")).setup()


@pytest.mark.parametrize("text, says", [
    ("participants: [1]\n", "participants: a study needs at least 2 participants"),
    ("participants: [4]\nvary:\n  design.bogus: [1]\n",
     "vary.design.bogus: with design.bogus = 1: unknown key"),
    ("participants: [4]\nrepetition: [1]\n", "repetition"),
    ("participants: [4]\nvary:\n  design.repetitions: [0]\n", "with design.repetitions = 0"),
])
def test_a_wrong_sweep_file_is_one_message(capsys, small, tmp_path, text, says):
    sweep = write_experiment(tmp_path, text, "sweep.yaml")
    code, out, err = _vtexp(capsys, "simulate", str(small), "--sweep", str(sweep), "-q",
                            "--workers", "1")
    assert code == 2 and says in err and "Traceback" not in err, err
    assert str(sweep) in err and len(err.strip().splitlines()) == 1
