"""The Python module against the `boucwen` binary on the same records: the same library
calls, so the same numbers, bit for bit (model files, design files and JSON compared as
bytes or exactly; only wall times left out)."""

import csv
import json

import numpy as np
import pytest

import boucwen
from conftest import without

# The held-out period of the benchmark's training record: 5 periods of 8192 samples.
PERIOD = 8192


@pytest.fixture(scope="module")
def bench_record(benchmark):
    return boucwen.read_record(benchmark, units={"y": "m"})


@pytest.fixture(scope="module")
def bench_cli(cli, benchmark, tmp_path_factory):
    """`boucwen identify --model auto --save --json` on the benchmark: its JSON and model file."""
    out = tmp_path_factory.mktemp("cli") / "bw.json"
    j = cli.json("identify", benchmark, "--y-unit", "m", "--model", "auto", "--save", out)
    return j, out


@pytest.fixture(scope="module")
def bench_model(bench_record):
    return boucwen.identify(bench_record)


def test_read_record_arrays_and_notes(cli, benchmark, bench_record, bench_cli):
    r = bench_record
    rows = np.loadtxt(benchmark, delimiter=",", skiprows=1)
    assert len(r) == len(r.u) == len(r.y) == len(r.t) == rows.shape[0] == 40960
    assert r.u.dtype == np.float64 and r.u.ndim == 1
    np.testing.assert_array_equal(r.u, rows[:, 1])
    np.testing.assert_allclose(r.y, rows[:, 2] * 1e6, rtol=1e-15)
    np.testing.assert_allclose(r.t, rows[:, 0], atol=1e-8)
    assert r.d is None and r.t0 == 0.0 and r.source == benchmark
    # The importer's samples, moved into NumPy once and read-only: what identify(r) uses.
    assert r.u is r.u and not r.u.flags.writeable
    with pytest.raises(ValueError):
        r.y[0] = 0.0
    # What the importer said: the command's line and the command's JSON.
    assert r.notes == 'comma-separated, with a header; t = "t", u = "u", y = "y" in m'
    text = cli.run("identify", benchmark, "--y-unit", "m", "--model", "linear").stdout
    assert text.splitlines()[0] == f"read as {r.notes}"
    assert r.import_info == bench_cli[0]["import"]


def test_identify_auto_is_the_cli_model_file_bit_for_bit(bench_model, bench_cli, tmp_path):
    cli_json, cli_file = bench_cli
    path = tmp_path / "py.json"
    bench_model.save(path)
    assert path.read_bytes() == cli_file.read_bytes()
    assert bench_model.to_json() == cli_file.read_text()
    # The report is `identify --json` without the wall times.
    assert without(bench_model.report, {"seconds"}) == without(cli_json, {"seconds"})
    assert bench_model.family == cli_json["chosen"] == "oscillator"
    assert bench_model.held_out_rms_um == cli_json["rms_um"]
    assert bench_model.params == cli_json["model"]["params"]


def test_identify_from_arrays_is_the_same_model(bench_record, bench_model):
    r = bench_record
    m = boucwen.identify(r.u, r.y, r.ts, source=r.source)
    assert m.to_json() == bench_model.to_json()
    # Lists and float32 are converted; the record still has to pass the importer's checks.
    assert boucwen.identify(list(r.u), list(r.y), r.ts, model="linear").family == "linear"


def test_model_load_simulate_matches_simulate_model(cli, benchmark, bench_cli, tmp_path):
    _, cli_file = bench_cli
    m = boucwen.Model.load(cli_file)
    assert m.report is None and m.family == "oscillator"
    out = tmp_path / "predicted.csv"
    cli.run("simulate", "--model", cli_file, "--input", benchmark, "--out", out)
    with open(out) as f:
        cli_y = np.array([float(row["y [um]"]) for row in csv.DictReader(f)])
    u = np.loadtxt(benchmark, delimiter=",", skiprows=1)[:, 1]
    y = m.simulate(u)
    assert y.dtype == np.float64 and y.shape == u.shape
    np.testing.assert_array_equal(y, cli_y)


def test_compare_on_the_held_out_period_matches_compare(cli, benchmark, bench_record, bench_cli):
    _, cli_file = bench_cli
    r = bench_record
    start = (len(r) - PERIOD) * r.ts
    end = len(r) * r.ts
    j = cli.json("compare", cli_file, benchmark, "--y-unit", "m", "--window", f"{start!r}:{end!r}")
    py = boucwen.Model.load(cli_file).compare(r, window=(start, end))
    simulated = py.pop("simulated")
    assert py == without(j, {"model_file"})
    assert py["window_samples"] == [len(r) - PERIOD, len(r)]
    # From arrays (at the model's ts) the same scores.
    arrays = boucwen.Model.load(cli_file).compare(r.u, r.y, window=(start, end))
    assert arrays["rms_um"] == py["rms_um"] and arrays["fit_pct"] == py["fit_pct"]
    np.testing.assert_array_equal(simulated, arrays["simulated"])


def test_identify_extended_and_enhanced_match_the_cli(cli, sine23, tmp_path):
    for model in ["extended", "enhanced"]:
        out = tmp_path / f"{model}.json"
        j = cli.json("identify", sine23, "--model", model, "--save", out)
        m = boucwen.identify(boucwen.read_record(sine23), model=model)
        assert m.to_json() == out.read_text()
        assert without(m.report, {"seconds"}) == without(j, {"seconds"})
        assert m.params["A1"] == j["params"]["a1"]


def test_diagnose_sine_json_is_the_cli_json(cli, sine23):
    d = boucwen.diagnose(boucwen.read_record(sine23))
    stdout = cli.run("diagnose", sine23, "--json").stdout
    assert d.to_json() == stdout.rstrip("\n")
    assert d.as_dict() == json.loads(stdout)
    assert d.analysis == "sine"
    # Typed findings with their evidence; the same verdicts.
    assert d.findings == json.loads(stdout)["findings"]
    kinds = [f["kind"] for f in d.findings]
    assert kinds and kinds[0] == "odd_harmonic"
    assert d.findings[0]["evidence"]["type"] == "harmonic"
    assert d.gain_pct == json.loads(stdout)["gain_pct"]
    assert d.report == cli.run("diagnose", sine23).stdout


def test_diagnose_from_arrays_same_verdict(sine23):
    r = boucwen.read_record(sine23)
    a = boucwen.diagnose(r.u, r.y, r.ts, source=r.source).as_dict()
    b = boucwen.diagnose(r).as_dict()
    b.pop("import")
    assert a == b


def test_diagnose_periodic_benchmark_json_is_the_cli_json(cli, benchmark, bench_record):
    d = boucwen.diagnose(bench_record)
    stdout = cli.run("diagnose", benchmark, "--y-unit", "m", "--json").stdout
    assert d.to_json() == stdout.rstrip("\n")
    assert d.analysis == "periodic"


def test_diagnose_rules_dict_and_file_as_the_cli(cli, sine23, tmp_path):
    rules = {"sine": {"min_periods": 6}}
    path = tmp_path / "rules.json"
    path.write_text(json.dumps(rules))
    stdout = cli.run("diagnose", sine23, "--json", "--rules", path).stdout
    r = boucwen.read_record(sine23)
    assert boucwen.diagnose(r, rules=str(path)).to_json() == stdout.rstrip("\n")
    assert boucwen.diagnose(r, rules=rules).to_json() == stdout.rstrip("\n")
    assert json.loads(stdout)["rules"]["sine"]["min_periods"] == 6


def test_design_is_the_cli_design_file(cli, sine23, tmp_path):
    out = tmp_path / "design.json"
    cli.run("board", "design", sine23, "-o", out, "--amplitude", 20)
    d = boucwen.design(sine23, amplitude=20)
    assert d.to_json() == out.read_text()
    assert boucwen.design([boucwen.read_record(sine23)], amplitude=20).to_json() == out.read_text()
    saved = tmp_path / "py-design.json"
    d.save(saved)
    assert boucwen.Design.load(saved).as_dict() == json.loads(out.read_text())


def test_sweep_table_is_the_cli_table(cli, tmp_path):
    j = cli.json("sweep", "--from", 23, "--to", 23, "--seconds", 3, "--out", tmp_path / "cli")
    t = boucwen.sweep(from_hz=23, to_hz=23, seconds=3)
    assert list(t)[:5] == ["freq_hz", "rms_extended_um", "rms_enhanced_um", "rmse_uf_um", "rmse_proposed_um"]
    assert all(isinstance(v, np.ndarray) and v.shape == (1,) for v in t.values())
    for name, column in t.items():
        cli_value = j["rows"][0][name]
        if cli_value is None:
            assert np.isnan(column[0]), name
        else:
            assert column[0] == cli_value, name


def test_errors_are_boucwen_error_with_the_cli_message(cli, tmp_path):
    assert issubclass(boucwen.Error, Exception)
    missing = tmp_path / "missing.csv"
    p = cli.run("diagnose", missing, ok=False)
    with pytest.raises(boucwen.Error) as e:
        boucwen.read_record(missing)
    assert p.stderr.strip() == f"boucwen: {e.value}"

    bad = tmp_path / "bad.csv"
    bad.write_text("t,u,y\n0,0,0\n0.001,1,abc\n0.002,0,1\n")
    p = cli.run("identify", bad, ok=False)
    with pytest.raises(boucwen.Error) as e:
        boucwen.read_record(bad)
    assert p.stderr.strip() == f"boucwen: {e.value}"
    assert 'column "y"' in str(e.value)

    t = np.arange(2000) * 1e-3
    with pytest.raises(boucwen.Error, match="no excitation"):
        boucwen.identify(np.full_like(t, 2.0), np.sin(t), 1e-3)
    with pytest.raises(boucwen.Error, match="fit-fraction"):
        boucwen.identify(np.sin(2 * np.pi * 5 * t), np.sin(2 * np.pi * 5 * t), 1e-3, fit_fraction=2.0)
    with pytest.raises(boucwen.Error, match="beyond"):
        boucwen.identify(np.full(10, 1e4), np.zeros(10), 1e-3)
    with pytest.raises(boucwen.Error, match="1-D"):
        boucwen.diagnose(np.zeros((3, 3)), np.zeros(9), 1e-3)
    with pytest.raises(boucwen.Error, match="model"):
        boucwen.identify(t, t, 1e-3, model="nonsense")
    with pytest.raises(boucwen.Error, match="units"):
        boucwen.read_record(missing, units={"x": "m"})
    with pytest.raises(boucwen.Error):
        boucwen.Model.load(tmp_path / "no-model.json")


def test_model_runs_on_any_drive_without_panicking(bench_model):
    # Drives far outside what the model was fitted on: an error or numbers, never a panic.
    for u in [np.zeros(0), np.zeros(1), np.full(100, 1e300), np.array([np.nan, 1.0])]:
        try:
            y = bench_model.simulate(u)
        except boucwen.Error:
            continue
        assert y.shape == u.shape
