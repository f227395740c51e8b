//! What a diagnosis found, as data: each finding's kind, whether its term was kept, and the
//! facts it rests on ([`Evidence`]), one variant per kind of finding. Nothing here is text:
//! the report layer ([`crate::report::diagnosis`]) renders findings as sentences and JSON.

use crate::model::terms::Relaxation;
use crate::signal::distortion::{Level, Parity};
use crate::signal::steady::DriveKind;

/// What a finding is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// An odd harmonic of the drive (order ≥ 3).
    OddHarmonic,
    /// An even harmonic of the drive.
    EvenHarmonic,
    /// A slow trend not locked to the drive.
    Drift,
    /// The drive explains too little of the output: another input or a disturbance drives it.
    OtherInput,
    /// The drive or the output is flattened at a level (an amplifier's rails, a sensor's
    /// range).
    Saturation,
    /// A slow relaxation that follows the drive's history.
    Creep,
    /// The output answers the drive later than the model does.
    InputDelay,
    /// Odd nonlinear distortion under a periodic or multisine drive.
    OddDistortion,
    /// Even nonlinear distortion under a periodic or multisine drive.
    EvenDistortion,
    /// Hysteresis as a restoring force inside the structure (the Bouc–Wen oscillator), not
    /// at the drive.
    RestoringForce,
}

impl Kind {
    /// The JSON name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Kind::OddHarmonic => "odd_harmonic",
            Kind::EvenHarmonic => "even_harmonic",
            Kind::Drift => "drift",
            Kind::OtherInput => "other_input",
            Kind::Saturation => "saturation",
            Kind::Creep => "creep",
            Kind::InputDelay => "input_delay",
            Kind::OddDistortion => "odd_distortion",
            Kind::EvenDistortion => "even_distortion",
            Kind::RestoringForce => "restoring_force_hysteresis",
        }
    }

    /// The harmonic kind of an order: odd from 3, even.
    pub fn of_order(order: u32) -> Kind {
        if order % 2 == 1 { Kind::OddHarmonic } else { Kind::EvenHarmonic }
    }

    /// The distortion kind of a parity.
    pub fn of_parity(p: Parity) -> Kind {
        match p {
            Parity::Odd => Kind::OddDistortion,
            Parity::Even => Kind::EvenDistortion,
        }
    }
}

/// What a term did in the forward selection: the held-out RMS before and after it was
/// added, and whether it was added to the baseline itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// Held-out RMS before (µm).
    pub before_um: f64,
    /// Held-out RMS after (µm).
    pub after_um: f64,
    /// Added to the baseline (the first term kept).
    pub first: bool,
}

impl Step {
    /// `100·(1 − after/before)`.
    pub fn gain_pct(&self) -> f64 {
        100.0 * (1.0 - self.after_um / self.before_um.max(1e-300))
    }
}

/// One named cause, with its evidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Finding {
    /// What it is.
    pub kind: Kind,
    /// Harmonic order (harmonics only).
    pub order: Option<u32>,
    /// Frequency (Hz): the harmonic's, the middle of a distortion's band, or 0.
    pub freq_hz: f64,
    /// Whether its term is in the extended model.
    pub kept: bool,
    /// A kept term: the share of the baseline's held-out residual power its term removed
    /// (when it was added). Not kept: its share of the extended model's residual power.
    pub residual_share: f64,
    /// What the term carries in the extended model: the held-out RMS of the change of the
    /// model's output when the term is removed (µm; a drift line counted from its level in
    /// the middle of the fitted half; creep over the whole run after the start-up, from its
    /// last level; an input delay over the start-up it was found on), at most the held-out
    /// RMS of the model's output about its mean. Not kept: the RMS of the structure in the
    /// residual.
    pub term_rms_um: f64,
    /// Held-out RMS of the model once its term was added (µm); `None` if not kept.
    pub rms_with_term_um: Option<f64>,
    /// The facts the finding rests on.
    pub evidence: Evidence,
}

impl Finding {
    /// A level and its unit where one applies: a saturation's (V of the drive, µm of the
    /// output), an input delay's (samples), a distortion's (dB above the noise).
    pub fn level(&self) -> Option<(f64, &'static str)> {
        match &self.evidence {
            Evidence::OutputSaturation(e) => Some((e.level_um(), "µm")),
            Evidence::DriveSaturation(e) => Some((e.levels_v[1].abs().max(e.levels_v[0].abs()), "V")),
            Evidence::InputDelay(e) => Some((e.samples, "samples")),
            Evidence::Distortion(e) => Some((e.level().db, "dB above noise")),
            Evidence::UnexplainedDistortion { level, .. } => Some((level.db, "dB above noise")),
            _ => None,
        }
    }

    /// The band (Hz) a distortion shows in.
    pub fn band_hz(&self) -> Option<[f64; 2]> {
        match &self.evidence {
            Evidence::Distortion(e) => e.level().band_hz,
            Evidence::UnexplainedDistortion { level, .. } => level.band_hz,
            _ => None,
        }
    }

    /// A sensor's range: the drive amplitude (V, about the drive's mean) with which the
    /// model, its output clamp removed, stays inside the range.
    pub fn drive_within_range_v(&self) -> Option<f64> {
        match &self.evidence {
            Evidence::OutputSaturation(e) => e.within_range.map(|w| w.amplitude_v),
            _ => None,
        }
    }
}

/// The facts a finding rests on, one variant per kind.
#[derive(Clone, Debug, PartialEq)]
pub enum Evidence {
    /// A harmonic branch kept.
    Harmonic(HarmonicEvidence),
    /// A drift line kept.
    Drift(TrendEvidence),
    /// The baseline explains less of the held-out output than the rules ask.
    OtherInput {
        /// The baseline's held-out fit (%; NaN when not measured).
        fit_pct: f64,
        /// The least the rules ask (`checks.min_fit_pct`).
        min_fit_pct: f64,
    },
    /// A clamp of the output kept (a sensor's range, a stop).
    OutputSaturation(OutputSaturationEvidence),
    /// A clamp of the drive kept (an amplifier's rails).
    DriveSaturation(DriveSaturationEvidence),
    /// Creep states kept.
    Creep(CreepEvidence),
    /// An input delay the step onto the drive shows.
    InputDelay(DelayEvidence),
    /// A stiffening term kept under a periodic or multisine drive.
    Distortion(DistortionEvidence),
    /// The hysteresis sits in the restoring force: the oscillator beat the extended model.
    RestoringForce(PlacementEvidence),
    /// A harmonic the extended model leaves and no term removed.
    UnexplainedHarmonic {
        /// Its peak in the extended model's held-out residual (µm).
        amp_um: f64,
        /// Its share of that residual's power.
        share: f64,
    },
    /// A slow trend the extended model leaves and no term removed.
    UnexplainedTrend {
        /// Its RMS (µm).
        rms_um: f64,
        /// Its slope (µm/s).
        slope_um_per_s: f64,
        /// Its share of the extended model's residual power.
        share: f64,
    },
    /// Distortion of a parity the model leaves in its held-out residual and no term removed.
    UnexplainedDistortion {
        /// Its parity.
        parity: Parity,
        /// Its level at the lines of that parity.
        level: Level,
        /// Its share of the residual's power at the distortion lines of both parities.
        share: f64,
        /// Whether the lines are the drive's own harmonics (a triangle's odd lines): what is
        /// off is the model's response to them.
        on_drive_lines: bool,
    },
}

/// Where the hysteresis sits: the Bouc–Wen oscillator (hysteresis as a restoring force)
/// against the extended model (hysteresis at the drive), on the same held-out data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlacementEvidence {
    /// The held-out RMS of the best model with the hysteresis at the drive: the extended
    /// model with the terms kept (µm).
    pub at_drive_um: f64,
    /// The oscillator's held-out RMS (µm).
    pub restoring_um: f64,
    /// The least gain the rules ask of another family (`families.min_gain`).
    pub min_gain: f64,
    /// The output's noise floor held out (µm).
    pub noise_um: f64,
    /// The most the oscillator may leave, in multiples of the noise (`families.max_noise_ratio`).
    pub max_noise_ratio: f64,
    /// The oscillator's parameters (SI, metres).
    pub params: crate::model::oscillator::OscillatorParams,
    /// Its integration substeps per sample.
    pub substeps: usize,
}

impl PlacementEvidence {
    /// `1 − restoring/at_drive`.
    pub fn gain(&self) -> f64 {
        1.0 - self.restoring_um / self.at_drive_um.max(1e-300)
    }

    /// What the oscillator leaves, in multiples of the noise floor.
    pub fn noise_ratio(&self) -> f64 {
        self.restoring_um / self.noise_um.max(1e-300)
    }

    /// Whether the rules name the restoring force: the gain and the noise both met.
    pub fn meets_rules(&self) -> bool {
        self.gain() >= self.min_gain && self.noise_ratio() <= self.max_noise_ratio
    }
}

/// A harmonic branch kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicEvidence {
    /// Its order.
    pub order: u32,
    /// Its frequency (Hz).
    pub freq_hz: f64,
    /// The output's harmonic there (µm peak)...
    pub output_um: f64,
    /// ...relative to the output's fundamental.
    pub output_rel: f64,
    /// Its peak in the baseline's held-out residual (µm)...
    pub residual_um: f64,
    /// ...and its share of that residual's power.
    pub residual_share: f64,
    /// What the residual says of it.
    pub reading: ResidualReading,
    /// What the branch did.
    pub step: Step,
    /// The drive's own harmonic of that order, when it carries some
    /// (`sine.drive_harmonic_note`).
    pub drive: Option<DriveHarmonic>,
    /// A fitted resonance near the harmonic (`sine.near_resonance`).
    pub resonance: Option<NearResonance>,
}

/// What the baseline's residual says of a harmonic a branch was kept for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualReading {
    /// It holds at least `terms.unexplained_share` of the residual's power.
    Holds,
    /// The baseline imitates it by bending its structure and pays at other harmonics (the
    /// first term, holding less).
    Imitated,
    /// Neither (a later term).
    Plain,
}

/// The drive's own harmonic of a finding's order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveHarmonic {
    /// Its amplitude relative to the drive's fundamental.
    pub rel: f64,
    /// What it accounts for in the output through the model (µm peak).
    pub part_um: f64,
}

/// A fitted structure's resonance near a harmonic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearResonance {
    /// The resonance (Hz).
    pub hz: f64,
    /// Only the baseline's structure has it there: one sine places a resonance only through
    /// the harmonics it makes, and a multisine or a sweep through it would tell.
    pub needs_confirming: bool,
}

/// A slow trend: the residual's, and what its term did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrendEvidence {
    /// Its share of the baseline's held-out residual power.
    pub share: f64,
    /// Its RMS (µm).
    pub rms_um: f64,
    /// Its mean (µm).
    pub mean_um: f64,
    /// Its slope (µm/s).
    pub slope_um_per_s: f64,
    /// What the term did.
    pub step: Step,
}

/// A clamp of the output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputSaturationEvidence {
    /// The level the output sits at from above (µm), if it does.
    pub top_um: Option<f64>,
    /// The level it sits at from below (µm), if it does.
    pub bottom_um: Option<f64>,
    /// Share of the steady output's samples on the plateaus.
    pub share: f64,
    /// What the clamp did.
    pub step: Step,
    /// The drive that keeps the output inside the range, if the model leaves it.
    pub within_range: Option<WithinRange>,
}

impl OutputSaturationEvidence {
    /// The level reported: the top plateau's, else the bottom's.
    pub fn level_um(&self) -> f64 {
        self.top_um.or(self.bottom_um).unwrap_or(f64::NAN)
    }
}

/// The drive with which the model, its output clamp removed, stays inside the range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WithinRange {
    /// Its share of the record's drive.
    pub scale: f64,
    /// Its amplitude (V).
    pub amplitude_v: f64,
}

/// A clamp of the drive.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveSaturationEvidence {
    /// The drive's levels `[lo, hi]` (V) beyond which the actuator stops following it.
    pub levels_v: [f64; 2],
    /// The output's odd harmonics of the series (order, amplitude relative to the
    /// fundamental).
    pub series: Vec<(u32, f64)>,
    /// What the clamp did.
    pub step: Step,
}

/// Creep states.
#[derive(Clone, Debug, PartialEq)]
pub struct CreepEvidence {
    /// The relaxations the fit left with a gain.
    pub relaxations: Vec<Relaxation>,
    /// The trend of the baseline's residual they replace.
    pub trend: TrendEvidence,
}

/// An input delay.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DelayEvidence {
    /// The delay (samples).
    pub samples: f64,
    /// The sample interval (s).
    pub ts: f64,
    /// Length of the criterion after the step onto the drive (s).
    pub window_s: f64,
    /// RMS error over it of the model fitted without a delay (µm)...
    pub startup_without_um: f64,
    /// ...and with it.
    pub startup_with_um: f64,
    /// The extended model's held-out RMS before the delay (µm)...
    pub held_out_before_um: f64,
    /// ...and with it, if it kept it.
    pub held_out_after_um: Option<f64>,
    /// The smallest delay named (`causes.min_delay_samples`).
    pub min_samples: f64,
    /// The most the held-out RMS may rise for the delay to be kept
    /// (`causes.delay_held_out_slack`).
    pub held_out_slack: f64,
}

/// Which lines a distortion shows at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lines {
    /// The odd lines a multisine leaves out.
    OddLeftOut,
    /// The odd lines (of a drive that excites only odd ones).
    Odd,
    /// The even lines.
    Even,
}

/// A stiffening term kept under a periodic or multisine drive.
#[derive(Clone, Debug, PartialEq)]
pub struct DistortionEvidence {
    /// The parity it addresses.
    pub parity: Parity,
    /// The lines it shows at.
    pub lines: Lines,
    /// The data's level at the lines the drive leaves free (`None`: the drive excites every
    /// line of the parity, a triangle's odd lines).
    pub data: Option<Level>,
    /// What the term accounts for at the lines of its parity.
    pub contribution: Level,
    /// The drive's kind.
    pub drive: DriveKind,
    /// The baseline's label, and its held-out residual's level at those lines.
    pub baseline: (String, Level),
    /// What the term did.
    pub step: Step,
    /// The model's held-out residual's level there after the term.
    pub after: Level,
    /// The stiffening's power, coefficient and reference deflection (µm).
    pub stiffening: Option<(u32, f64, f64)>,
}

impl DistortionEvidence {
    /// The level reported: the data's at the free lines, else the term's contribution.
    pub fn level(&self) -> Level {
        self.data.unwrap_or(self.contribution)
    }
}

/// A term's description: what the forward selection tried.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Term {
    /// A harmonic branch of an order.
    Branch(u32),
    /// A drift line.
    Drift,
    /// A clamp of the output.
    OutputClamp,
    /// A clamp of the drive.
    DriveClamp,
    /// Creep states.
    Creep,
    /// A stiffening of a parity (periodic drives).
    Stiffening(Parity),
}

/// Why a term that gained enough was not kept.
#[derive(Clone, Debug, PartialEq)]
pub enum NotKept {
    /// The drive's own harmonic of the term's order accounts for too much of the output's
    /// (`sine.drive_share_max`).
    DriveHarmonic {
        /// The order.
        order: u32,
        /// The drive's harmonic relative to its fundamental.
        drive_rel: f64,
        /// The share of the output's harmonic it accounts for.
        share: f64,
        /// What the branch would have gained (%).
        gain_pct: f64,
        /// The drive distortion below which the drive's harmonics are left out
        /// (`sine.drive_distortion_floor`).
        floor: f64,
    },
    /// The term carries less than the rules ask.
    CarriesTooLittle {
        /// What it carries (µm).
        carried_um: f64,
        /// What a term must carry (µm).
        need_um: f64,
        /// The share of the output that is (`terms.min_term_rel`).
        min_term_rel: f64,
        /// A drift's or creep's alternative: this many times the residual's noise
        /// (`sine.drift_noise_factor`).
        noise_factor: Option<f64>,
        /// Under a periodic drive, what it removes from the held-out residual (µm), against
        /// `periodic.noise_multiple` times the noise (the multiple, the noise in µm).
        removed: Option<(f64, f64, f64)>,
    },
    /// Another term of the round lowered the held-out RMS further.
    LowerRms {
        /// The winner.
        winner: Term,
        /// Its held-out RMS (µm).
        winner_um: f64,
        /// This term's (µm).
        this_um: f64,
        /// The round.
        round: usize,
    },
    /// Another term of the round had more evidence in the record.
    MoreEvidence {
        /// The winner.
        winner: Term,
        /// Its evidence (µm RMS, or dB for a periodic drive's parities).
        winner_evidence: f64,
        /// This term's.
        this_evidence: f64,
        /// Whether the evidence is in dB (a parity's level) rather than µm.
        db: bool,
        /// The round.
        round: usize,
    },
}

/// What the record says about the fitted structure's resonance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resonance {
    /// The fitted structure's poles are real.
    NoneFitted,
    /// The model explains too little of the output to say.
    NotAssessed,
    /// A line the record excites lies near it: the drive (order 1) or an output harmonic.
    Excited {
        /// The order of the line (1: the drive).
        order: u32,
        /// Its frequency (Hz).
        freq_hz: f64,
    },
    /// A harmonic of the residual near it holds enough of its power.
    InResidual {
        /// Its frequency (Hz).
        freq_hz: f64,
    },
    /// Nothing the record excites lies near the fitted resonance.
    NotIdentifiable {
        /// The fitted resonance (Hz).
        fitted_hz: f64,
        /// The drive (Hz).
        drive_hz: f64,
        /// The highest output harmonic the record shows (Hz).
        top_hz: f64,
    },
}

/// Why a model's free run is not stable.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Instability {
    /// A pole on or outside the unit circle.
    Pole {
        /// Its modulus.
        modulus: f64,
        /// The AR part `[a1, a2]`.
        ar: [f64; 2],
    },
    /// The free run leaves the physical range (±`limit_um`), `after_s` into the held-out
    /// part.
    LeavesRange {
        /// The range (µm).
        limit_um: f64,
        /// When (s).
        after_s: f64,
    },
    /// The free run leaves `spans` times the output's span beyond its range `[lo, hi]`.
    RunsAway {
        /// How many spans.
        spans: f64,
        /// The output's range (µm).
        range_um: [f64; 2],
        /// When (s).
        after_s: f64,
    },
}

/// Why a model fitted at one amplitude may hold at that amplitude only.
#[derive(Clone, Debug, PartialEq)]
pub struct Narrow {
    /// `γ + β` of its loop; `≤ 0` is outside the Bouc–Wen model's bounded class.
    pub gamma_plus_beta: f64,
    /// Whether the loop is outside the bounded class.
    pub unbounded: bool,
    /// The drive scales at which its free run diverges.
    pub diverges_at: Vec<f64>,
    /// The drive scales checked (`checks.other_amplitudes`).
    pub scales: Vec<f64>,
}

/// A term the forward selection may try.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// What it would model.
    pub kind: Kind,
    /// Harmonic order (harmonics only).
    pub order: Option<u32>,
    /// Frequency (Hz; 0 for drift).
    pub freq_hz: f64,
    /// Its share of the baseline's held-out residual power.
    pub share: f64,
    /// Its amplitude in the baseline's residual (µm; harmonic peak or trend RMS).
    pub amp: f64,
    /// How much of the record it accounts for (µm RMS): a harmonic's RMS in the output, the
    /// trend's RMS in the baseline's residual. What orders the terms that would be kept:
    /// the extended model can imitate one harmonic with its own loop and then needs a branch
    /// to cancel what its loop does elsewhere, a branch that carries much in the model but
    /// stands for little in the record.
    pub evidence_um: f64,
    /// A saturation of the output: the range `[lo, hi]` (µm) its plateaus show (`None`: of
    /// the drive, or not a saturation).
    pub output_range: Option<[f64; 2]>,
}

impl Candidate {
    /// The term it would add.
    pub fn term(&self) -> Term {
        match (self.kind, self.order) {
            (Kind::Drift, _) => Term::Drift,
            (Kind::Saturation, _) if self.output_range.is_some() => Term::OutputClamp,
            (Kind::Saturation, _) => Term::DriveClamp,
            (Kind::Creep, _) => Term::Creep,
            (Kind::OddDistortion, _) => Term::Stiffening(Parity::Odd),
            (Kind::EvenDistortion, _) => Term::Stiffening(Parity::Even),
            (_, Some(n)) => Term::Branch(n),
            (_, None) => Term::Drift,
        }
    }

    /// A saturation or creep: a physical term, chosen by its held-out RMS rather than by
    /// its evidence.
    pub fn physical(&self) -> bool {
        matches!(self.kind, Kind::Saturation | Kind::Creep)
    }
}

/// One term tried in one round of the forward selection.
#[derive(Clone, Debug, PartialEq)]
pub struct Trial {
    /// Round (0: added to the baseline).
    pub round: usize,
    /// The term.
    pub candidate: Candidate,
    /// Held-out RMS with it (µm).
    pub rms_um: f64,
    /// What the term carries in that model (µm, see [`Finding::term_rms_um`]).
    pub term_rms_um: f64,
    /// How much it lowered the held-out RMS of the round's model (%).
    pub gain_pct: f64,
    /// Whether this trial's term was kept.
    pub kept: bool,
    /// Why a trial that gained at least `terms.min_gain` was not kept.
    pub reason: Option<NotKept>,
}
