//! Nothing that runs per sample allocates: every operation timed in `benches/latency.rs`
//! (model steps, RLS updates, compensator steps, the peer controllers' steps), the open
//! loop and the online identifier, in `f32` and `f64`, is run for many samples while a
//! global allocator counts the allocations made by the running thread.
//!
//! The counter is per thread, so the harness running other tests (or printing) on other
//! threads at the same time cannot pollute it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use boucwen_core::Real;
use boucwen_core::compensator::{
    Compensator, CompensatorConfig, HarmonicSpec, PhaseRule, Saturation, harmonic_response,
};
use boucwen_core::controllers::{
    Controller, ORC_CAPACITY, OpenLoop, OrcController, PiController, TuneOptions, tune,
};
use boucwen_core::ident::{IdentConfig, Identifier};
use boucwen_core::model::{BoucWenParams, Classic, EnhancedParams, ExtendedParams, HarmonicBranch, Model};
use boucwen_core::rls::{Rls, RlsConfig};
use boucwen_core::signal::{Oscillator, Sine};
use nalgebra::{Complex, SVector};

thread_local! {
    // Const-initialised and without a destructor: reading it never allocates, which matters
    // because it is read from inside the allocator.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

/// `System`, counting the calls that obtain memory (alloc, alloc_zeroed, realloc) per thread.
struct Counting;

fn count_one() {
    // `try_with` fails only while the thread is being torn down; nothing is measured then.
    let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged, so the
// `GlobalAlloc` contract holds exactly as it does for `System`; the counting touches only a
// thread-local `Cell` and never allocates.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: forwarded unchanged (see above).
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: forwarded unchanged.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        // SAFETY: forwarded unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by this thread while `f` runs.
fn allocations_in(f: impl FnOnce()) -> u64 {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

const TS: f64 = 1e-3;
const SAMPLES: usize = 10_000;

fn drive() -> Oscillator {
    Oscillator::new(23.0, TS).unwrap()
}

/// The benchmark's model: µm/V, resonance near 70 Hz at 1 kHz.
fn extended<T: Real>() -> ExtendedParams<T, 2> {
    let w0 = core::f64::consts::TAU * 70.0 * TS;
    ExtendedParams {
        bw: BoucWenParams {
            a1: T::lit(20.0),
            a: T::lit(6.0),
            a0: T::lit(0.5),
            gamma: T::lit(2.0),
            beta: T::lit(3.0),
        },
        ar: [T::lit(2.0 * 0.97 * w0.cos()), T::lit(-0.97 * 0.97)],
    }
}

fn enhanced3<T: Real>() -> EnhancedParams<T, 2, 2, 1> {
    EnhancedParams {
        base: extended(),
        branches: [HarmonicBranch {
            order: 3,
            alpha_s: T::lit(0.10),
            alpha_c: T::lit(-0.06),
            ar: [T::lit(0.3), T::lit(-0.1)],
        }],
        drive: drive(),
    }
}

/// A 1.5 V, 23 Hz drive (into the loop's saturation) with a slow second tone.
fn inputs<T: Real>() -> Vec<T> {
    let (mut a, mut b) = (Sine::new(1.5, drive()), Sine::new(0.2, Oscillator::new(3.1, TS).unwrap()));
    (0..SAMPLES).map(|_| T::lit(a.next_sample() + b.next_sample())).collect()
}

/// Runs `step` once for warm-up, then over every input while counting; returns the count
/// and a checksum of the outputs (so the work is observably done).
fn count_steps<T: Real, M: Model<T>>(model: &M) -> (u64, f64) {
    let u = inputs::<T>();
    let mut state = model.initial_state();
    model.step(&mut state, u[0]);
    let mut sum = 0.0;
    let n = allocations_in(|| {
        for &uk in &u {
            sum += model.step(&mut state, uk).to_f64();
        }
    });
    (n, sum)
}

/// `N`-parameter regression data with uniform regressors.
fn regression<T: Real, const N: usize>() -> Vec<(SVector<T, N>, T)> {
    let (mut a, mut b) = (Sine::new(1.0, Oscillator::new(41.0, TS).unwrap()), Sine::new(1.0, drive()));
    (0..SAMPLES)
        .map(|k| {
            let x =
                SVector::<f64, N>::from_fn(|i, _| if i % 2 == 0 { a.next_sample() } else { b.next_sample() })
                    + SVector::from_fn(|i, _| ((k * 31 + i * 17) % 101) as f64 / 101.0);
            let y = x.sum();
            (x.map(T::lit), T::lit(y))
        })
        .collect()
}

fn count_rls<T: Real, const N: usize>() -> (u64, u32) {
    let data = regression::<T, N>();
    let mut rls =
        Rls::new(RlsConfig::with_forgetting(T::lit(0.999), T::lit(100.0)), SVector::zeros()).unwrap();
    rls.update(&data[0].0, data[0].1).unwrap();
    let n = allocations_in(|| {
        for (x, y) in &data {
            rls.update(x, *y).unwrap();
            rls.update_with_error(x, *y - rls.predict(x)).unwrap();
        }
    });
    (n, rls.stats().updates)
}

/// The benchmark's compensator on a closed loop with an enhanced plant (plant steps
/// included in the count; they are model steps).
fn count_compensator<T: Real>() -> (u64, T) {
    let g = harmonic_response(&extended::<f64>(), 3, 23.0, TS, PhaseRule::Model);
    let mut comp = Compensator::<T, 2, 1>::new(CompensatorConfig {
        model: extended(),
        drive: drive(),
        harmonics: [HarmonicSpec { order: 3, response: Complex::new(T::lit(g.re), T::lit(g.im)) }],
        rls: RlsConfig::with_forgetting(T::lit(0.999), T::lit(1e-2)),
        saturation: Saturation::symmetric(T::lit(10.0)),
        uc_max: T::lit(5.0),
    })
    .unwrap();
    let plant = enhanced3::<T>();
    let mut state = plant.initial_state();
    let mut reference = Sine::new(T::lit(20.0), drive());
    let mut y = plant.step(&mut state, comp.step(reference.next_sample(), None).unwrap().u);
    let n = allocations_in(|| {
        for k in 0..SAMPLES {
            // Every 100th measurement lost: the step without adaptation is covered too.
            let measured = if k % 100 == 99 { None } else { Some(y) };
            let out = comp.step(reference.next_sample(), measured).unwrap();
            y = plant.step(&mut state, out.u);
        }
    });
    (n, comp.weights(0).unwrap().0)
}

/// A controller on the same closed loop as the compensator; returns the count and the
/// last input applied.
fn count_controller<T: Real, C: Controller<T>>(mut ctrl: C) -> (u64, T) {
    let plant = enhanced3::<T>();
    let mut state = plant.initial_state();
    let mut reference = Sine::new(T::lit(20.0), drive());
    let mut u = ctrl.step(reference.next_sample(), None).unwrap().u;
    let mut y = plant.step(&mut state, u);
    let n = allocations_in(|| {
        for k in 0..SAMPLES {
            let measured = if k % 100 == 99 { None } else { Some(y) };
            u = ctrl.step(reference.next_sample(), measured).unwrap().u;
            y = plant.step(&mut state, u);
        }
    });
    (n, u)
}

fn count_identifier<T: Real>() -> (u64, u32) {
    let truth = enhanced3::<T>();
    let mut id = Identifier::<T, 2, 2, 1, 11>::new(
        IdentConfig::gradient::<2>(T::lit(0.9995), T::lit(1.0)),
        drive(),
        [3],
    )
    .unwrap();
    let u = inputs::<T>();
    let mut state = truth.initial_state();
    id.update(u[0], truth.step(&mut state, u[0])).unwrap();
    let n = allocations_in(|| {
        for &uk in &u {
            id.update(uk, truth.step(&mut state, uk)).unwrap();
        }
    });
    (n, id.stats().updates)
}

fn check_precision<T: Real>(name: &str) {
    let classic = Classic(BoucWenParams { a0: T::zero(), ..extended::<T>().bw });
    for (what, (n, sum)) in [
        ("classic step", count_steps(&classic)),
        ("extended step", count_steps(&extended::<T>())),
        ("enhanced3 step", count_steps(&enhanced3::<T>())),
    ] {
        assert_eq!(n, 0, "{name} {what}: {n} allocations in {SAMPLES} steps");
        assert!(sum.is_finite() && sum != 0.0, "{name} {what}: outputs sum to {sum}");
    }
    for (what, (n, updates)) in [("rls 11", count_rls::<T, 11>()), ("rls 7", count_rls::<T, 7>())] {
        assert_eq!(n, 0, "{name} {what}: {n} allocations in {} updates", 2 * SAMPLES);
        assert_eq!(updates as usize, 2 * SAMPLES + 1, "{name} {what}: updates rejected");
    }
    let (n, weight) = count_compensator::<T>();
    assert_eq!(n, 0, "{name} compensator: {n} allocations in {SAMPLES} steps");
    assert!(weight.is_finite() && weight != T::zero(), "{name} compensator did not adapt");
    let tuning = tune(
        &extended::<T>(),
        drive(),
        T::lit(TS),
        Saturation::symmetric(T::lit(10.0)),
        &TuneOptions::default(),
    )
    .unwrap();
    for (what, (n, u)) in [
        ("open loop", count_controller(OpenLoop::new(tuning.open_loop).unwrap())),
        ("PI", count_controller(PiController::new(tuning.pi.pi).unwrap())),
        (
            "ORC",
            count_controller(OrcController::<T, ORC_CAPACITY>::new(tuning.pi.pi, tuning.orc.orc).unwrap()),
        ),
    ] {
        assert_eq!(n, 0, "{name} {what} controller: {n} allocations in {SAMPLES} steps");
        assert!(u.is_finite(), "{name} {what} controller: u = {u}");
    }
    let (n, updates) = count_identifier::<T>();
    assert_eq!(n, 0, "{name} identifier: {n} allocations in {SAMPLES} updates");
    assert_eq!(updates as usize, SAMPLES + 1, "{name} identifier: updates rejected");
}

#[test]
fn the_counter_sees_allocations_on_this_thread() {
    let n = allocations_in(|| {
        let v: Vec<u64> = std::hint::black_box(vec![1, 2, 3]);
        let mut s = String::from("x");
        s.push_str(&"y".repeat(100));
        std::hint::black_box((v, s));
    });
    assert!(n >= 3, "counted {n} allocations");
}

#[test]
fn no_per_sample_operation_allocates_in_f64() {
    check_precision::<f64>("f64");
}

#[test]
fn no_per_sample_operation_allocates_in_f32() {
    check_precision::<f32>("f32");
}
