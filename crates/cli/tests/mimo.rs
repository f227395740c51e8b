//! Records of several inputs and outputs end to end: a two-input two-output resonant structure
//! driven by random-phase multisines at two levels, written as NumPy files the way the Fine
//! Steering Mirror benchmark ships them. A static cubic on the inputs is hidden in one record:
//! `diagnose` must find nonlinear distortion that grows with the level there and not in the
//! linear control; `identify` keeps a realisation apart and scores the model on it; the model
//! file runs in `compare` and `simulate --model`; bad input gives one line.

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn boucwen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("boucwen-mimo-{}", std::process::id())).join(name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Samples per period, inputs and outputs, realisations, periods.
const N: usize = 512;
const M: usize = 2;
const R: usize = 4;
const P: usize = 2;

/// A tiny SplitMix64 for the phases and the noise (the test's own, to stay deterministic
/// whatever the library's generator is).
struct Gen(u64);
impl Gen {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.next().max(1e-300), self.next());
        (-2.0 * a.ln()).sqrt() * (TAU * b).cos()
    }
}

/// A `.npy` file of f64 in C order.
fn write_npy(path: &Path, shape: &[usize], data: &[f64]) {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({}), }}", dims.join(", "));
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in data {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

/// Two resonances (0.06 and 0.17 of the sample rate), each input reaching each output with
/// its own gain: `y_o = Σ_i g_oi (H₁ + H₂)(u_i + cubic·u_i³)`, plus white noise.
fn structure(u: &[Vec<f64>], cubic: f64, noise: f64, g: &mut Gen) -> Vec<Vec<f64>> {
    let gains = [[1.0, 0.4], [-0.3, 0.8]];
    let res = |f: f64, r: f64| (2.0 * r * (TAU * f).cos(), -r * r);
    let modes = [res(0.06, 0.93), res(0.17, 0.9)];
    let len = u[0].len();
    let mut y = vec![vec![0.0; len]; M];
    for (i, ui) in u.iter().enumerate() {
        let x: Vec<f64> = ui.iter().map(|v| v + cubic * v * v * v).collect();
        for (a1, a2) in modes {
            let mut w = vec![0.0; len];
            for k in 0..len {
                let prev = |d: usize| if k >= d { w[k - d] } else { 0.0 };
                let xin = if k >= 1 { x[k - 1] } else { 0.0 };
                w[k] = a1 * prev(1) + a2 * prev(2) + xin;
            }
            for o in 0..M {
                for k in 0..len {
                    y[o][k] += gains[o][i] * w[k];
                }
            }
        }
    }
    for yo in &mut y {
        for v in yo.iter_mut() {
            *v += noise * g.normal();
        }
    }
    y
}

/// A record of two levels (100 and 300 mV RMS per input) in `dir`: `u_TAG.npy`, `y_TAG.npy`
/// of shape (N, channel, realisation, period), outputs in µm.
fn write_record(dir: &Path, cubic: f64, seed: u64) {
    let mut g = Gen(seed);
    let lines: Vec<usize> = (1..N / 4).collect();
    for (tag, rms) in [("100mV", 0.1), ("300mV", 0.3)] {
        let mut u_all = vec![0.0; N * M * R * P];
        let mut y_all = vec![0.0; N * M * R * P];
        let mut group: Vec<Vec<f64>> = vec![];
        for r in 0..R {
            // Orthogonal multisines, as the benchmark's: each group of M realisations shares
            // random phases per input, input i of the group's realisation j signed by
            // T = [[1, 1], [1, −1]], so the group's input matrix at every line is unitary up to
            // a scale and the BLA's noise is not amplified by its inverse.
            if r % M == 0 {
                group = (0..M)
                    .map(|_| {
                        let ph: Vec<f64> = lines.iter().map(|_| TAU * g.next()).collect();
                        let one: Vec<f64> = (0..N)
                            .map(|k| {
                                lines
                                    .iter()
                                    .zip(&ph)
                                    .map(|(&l, p)| (TAU * (l * k) as f64 / N as f64 + p).cos())
                                    .sum()
                            })
                            .collect();
                        let s = (one.iter().map(|v| v * v).sum::<f64>() / N as f64).sqrt();
                        one.iter().map(|v| rms * v / s).collect()
                    })
                    .collect();
            }
            let sign = |i: usize| if i == 1 && r % M == 1 { -1.0 } else { 1.0 };
            // Three periods: the first lets the transient die out.
            let u: Vec<Vec<f64>> =
                (0..M).map(|i| (0..3 * N).map(|k| sign(i) * group[i][k % N]).collect()).collect();
            let y = structure(&u, cubic, 0.002, &mut g);
            for p in 0..P {
                for c in 0..M {
                    for k in 0..N {
                        let at = ((k * M + c) * R + r) * P + p;
                        u_all[at] = u[c][(p + 1) * N + k];
                        y_all[at] = y[c][(p + 1) * N + k];
                    }
                }
            }
        }
        write_npy(&dir.join(format!("u_{tag}.npy")), &[N, M, R, P], &u_all);
        write_npy(&dir.join(format!("y_{tag}.npy")), &[N, M, R, P], &y_all);
    }
}

fn json_of(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn nonlinear(j: &serde_json::Value) -> Vec<(bool, f64, f64)> {
    j["nonlinear_growth"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .map(|(o, g)| {
            let top = &j["levels"][1]["outputs"][o];
            (
                g["grows"].as_bool().unwrap(),
                top["nonlinear_um"].as_f64().unwrap(),
                top["noise_um"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn a_hidden_cubic_is_found_as_distortion_that_grows_with_the_level() {
    let (hidden, control) = (tmp("cubic"), tmp("linear"));
    write_record(&hidden, 2.0, 7);
    write_record(&control, 0.0, 7);
    let diag = |dir: &Path| {
        json_of(&boucwen(&["diagnose", dir.to_str().unwrap(), "--sample-rate", "1000", "--json"]))
    };
    let (h, c) = (diag(&hidden), diag(&control));
    assert_eq!((h["inputs"].as_u64(), h["outputs"].as_u64()), (Some(2), Some(2)));
    for (o, ((grows, nl, noise), (_, nl_lin, noise_lin))) in
        nonlinear(&h).into_iter().zip(nonlinear(&c)).enumerate()
    {
        assert!(grows, "output {o}: the cubic's distortion grows with the level");
        assert!(nl > 5.0 * noise, "output {o}: distortion {nl} µm well above the noise {noise} µm");
        assert!(nl > 10.0 * nl_lin, "output {o}: {nl} µm with the cubic, {nl_lin} µm without");
        assert!(
            nl_lin < 3.0 * noise_lin,
            "output {o}: the linear control's distortion {nl_lin} is noise ({noise_lin})"
        );
    }
    // The figures of the BLA, one per level.
    let dir = tmp("report");
    let out = boucwen(&[
        "diagnose",
        hidden.to_str().unwrap(),
        "--sample-rate",
        "1000",
        "--report",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("grows with the level"), "{text}");
    for f in ["bla-100mV.svg", "bla-300mV.svg", "diagnosis.json"] {
        assert!(dir.join(f).is_file(), "{f} written");
    }
}

#[test]
fn identify_keeps_a_realisation_apart_and_the_model_file_runs_elsewhere() {
    let dir = tmp("identify");
    write_record(&dir, 0.0, 11);
    let model = dir.join("model.json");
    let j = json_of(&boucwen(&[
        "identify",
        dir.to_str().unwrap(),
        "--sample-rate",
        "1000",
        "--model",
        "linear",
        "--order",
        "8",
        "--save",
        model.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(j["kept_apart_realisation"].as_u64(), Some(R as u64));
    let held: Vec<f64> =
        j["held_out"]["model_um"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    // The structure is linear of order 8 (two resonances from each of two inputs) with 0.002 µm
    // of noise per sample: held out the model is at the noise floor (the noise of one period,
    // ≈ 0.002 µm), at both levels.
    for (l, v) in held.iter().enumerate() {
        assert!(*v < 0.0035, "level {l}: {v} µm held out");
    }
    let freqs: Vec<f64> = j["modes"].as_array().unwrap().iter().map(|m| m["hz"].as_f64().unwrap()).collect();
    // The poles' natural frequencies: |ln z|·fs/2π of 0.93·e^{±i2π·0.06} and 0.9·e^{±i2π·0.17}.
    for f in [61.1, 170.8] {
        assert!(freqs.iter().any(|g| (g - f).abs() < 0.5), "a mode at {f} Hz in {freqs:?}");
    }
    // The model file on another record of the same structure (new phases and noise).
    let other = tmp("other");
    write_record(&other, 0.0, 12);
    let c = json_of(&boucwen(&[
        "compare",
        model.to_str().unwrap(),
        other.to_str().unwrap(),
        "--sample-rate",
        "1000",
        "--json",
    ]));
    for l in c["levels"].as_array().unwrap() {
        assert!(l["mean_um"].as_f64().unwrap() < 0.0035, "{l}");
    }
    // simulate --model: a drive of two columns in, two outputs out.
    let drive = other.join("drive.csv");
    let rows: String =
        (0..200).map(|k| format!("{},{}\n", (k as f64 * 0.3).sin(), (k as f64 * 0.7).cos())).collect();
    std::fs::write(&drive, format!("u1,u2\n{rows}")).unwrap();
    let out_csv = other.join("sim.csv");
    let out = boucwen(&[
        "simulate",
        "--model",
        model.to_str().unwrap(),
        "--input",
        drive.to_str().unwrap(),
        "--out",
        out_csv.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let written = std::fs::read_to_string(&out_csv).unwrap();
    assert!(written.lines().next().unwrap().contains("y2 [um]"), "{written:.200}");
    assert_eq!(written.lines().count(), 201);
    // A drive of whole periods of the training period (512 samples): two realisations written
    // one after the other, two periods each. Each run is simulated in its own steady state, so
    // the second run's rows are those of the second realisation simulated alone.
    let wave = |f: usize, ph: f64, k: usize| (TAU * (f * (k % N)) as f64 / N as f64 + ph).sin();
    let csv = |runs: &[(usize, usize)]| -> String {
        let mut rows = String::from("t,u1,u2\n");
        let mut k0 = 0;
        for &(f, periods) in runs {
            for k in 0..periods * N {
                rows += &format!(
                    "{},{},{}\n",
                    (k0 + k) as f64 * 1e-3,
                    0.2 * wave(f, 0.0, k),
                    0.1 * wave(2 * f, 1.0, k)
                );
            }
            k0 += periods * N;
        }
        rows
    };
    let sim = |name: &str, text: String| -> Vec<String> {
        let (drive, out_csv) = (other.join(format!("{name}.csv")), other.join(format!("{name}-out.csv")));
        std::fs::write(&drive, text).unwrap();
        let out = boucwen(&[
            "simulate",
            "--model",
            model.to_str().unwrap(),
            "--input",
            drive.to_str().unwrap(),
            "--out",
            out_csv.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(String::from_utf8_lossy(&out.stdout).contains("each in its steady state"));
        // The outputs only (the t column differs).
        std::fs::read_to_string(&out_csv)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').skip(3).collect::<Vec<_>>().join(","))
            .collect()
    };
    let both = sim("two-runs", csv(&[(3, 2), (5, 2)]));
    let alone = sim("one-run", csv(&[(5, 2)]));
    assert_eq!(&both[2 * N..], &alone[..], "the second run is in its own steady state");
    // The one-input reader says what the file is.
    let out = boucwen(&["compare", model.to_str().unwrap(), drive.to_str().unwrap()]);
    assert!(!out.status.success());
}

#[test]
fn bad_records_of_several_channels_get_one_line() {
    let dir = tmp("bad");
    write_record(&dir, 0.0, 3);
    // NumPy files carry no sample rate: the record runs per sample, and says so.
    let out = boucwen(&["diagnose", dir.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("no sample rate") && err.contains("--sample-rate"), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("cycles per sample"));
    // A y file without its u.
    std::fs::remove_file(dir.join("u_300mV.npy")).unwrap();
    let out = boucwen(&["diagnose", dir.to_str().unwrap(), "--sample-rate", "1000"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("no u_300mV beside y_300mV"), "{err}");
    // A truncated file.
    let y = dir.join("y_100mV.npy");
    let bytes = std::fs::read(&y).unwrap();
    std::fs::write(&y, &bytes[..bytes.len() / 2]).unwrap();
    let out = boucwen(&["diagnose", y.to_str().unwrap(), "--sample-rate", "1000"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("y_100mV.npy"), "{err}");
    // --columns with several inputs on a CSV.
    let csv = dir.join("run.csv");
    std::fs::write(&csv, "time,a,b,c,d\n0,1,2,3,4\n1,1,2,3,x\n").unwrap();
    let out = boucwen(&["diagnose", csv.to_str().unwrap(), "--columns", "t=time,u=a,b,y=c,d"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("run.csv:3") && err.contains("\"x\""), "{err}");
}

#[test]
fn the_hysteretic_model_beats_its_linear_part_where_the_cubic_is_hidden() {
    // A static cubic is not the family's own nonlinearity (hysteresis on the inputs, a
    // restoring force on the modes); the model still has to remove a tenth of what its linear
    // part leaves, held out, at every level.
    let dir = tmp("identify-cubic");
    write_record(&dir, 0.5, 5);
    let j = json_of(&boucwen(&[
        "identify",
        dir.to_str().unwrap(),
        "--sample-rate",
        "1000",
        "--order",
        "8",
        "--json",
    ]));
    assert_eq!(j["model"], "hysteretic");
    let v = |k: &str| -> Vec<f64> {
        j["held_out"][k].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
    };
    for (l, (m, lin)) in v("model_um").into_iter().zip(v("linear_um")).enumerate() {
        assert!(m < 0.9 * lin, "level {l}: model {m} µm, its linear part {lin} µm held out");
    }
}

#[test]
fn outputs_in_metres_are_read_as_metres_without_a_unit_and_said_so() {
    let dir = tmp("metres");
    write_record(&dir, 0.0, 9);
    let um = json_of(&boucwen(&["diagnose", dir.to_str().unwrap(), "--sample-rate", "1000", "--json"]));
    // The same outputs written in metres.
    for tag in ["100mV", "300mV"] {
        let p = dir.join(format!("y_{tag}.npy"));
        let bytes = std::fs::read(&p).unwrap();
        let start = bytes.len() - N * M * R * P * 8;
        let mut out = bytes[..start].to_vec();
        for c in bytes[start..].chunks(8) {
            out.extend_from_slice(&(f64::from_le_bytes(c.try_into().unwrap()) * 1e-6).to_le_bytes());
        }
        std::fs::write(&p, out).unwrap();
    }
    let out = boucwen(&["diagnose", dir.to_str().unwrap(), "--sample-rate", "1000", "--json"]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(err.contains("outputs read in m"), "{err}");
    let m = json_of(&out);
    let rms = |j: &serde_json::Value| j["levels"][1]["outputs"][0]["rms_um"].as_f64().unwrap();
    assert!((rms(&m) / rms(&um) - 1.0).abs() < 1e-9, "{} vs {} µm", rms(&m), rms(&um));
    // Said otherwise, it is read as said.
    let out =
        boucwen(&["diagnose", dir.to_str().unwrap(), "--sample-rate", "1000", "--y-unit", "um", "--json"]);
    assert!(rms(&json_of(&out)) < 1e-5);
}
