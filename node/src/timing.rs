//! Where a window's and a query's time goes (ARCHITECTURE.md §6): the pipeline's stages, the durations of
//! one pass, and the recent samples per stage that the status message reports as p50 / p99.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// One stage of the pipeline, in data-flow order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    /// Decode, validate and sync one message (node loop).
    Ingest,
    /// The semantic model on one keyframe and its per-pixel classes, run when the keyframe
    /// arrives and the worker is idle (outside every window's time: the window then only pools
    /// the cached features).
    Keyframe,
    /// The reconstruction model's forward pass, inputs and outputs included (the semantic
    /// features of views not computed ahead run beside it, sharing the cores).
    Model,
    /// Gaussians from the model's outputs (sensor depth in RGB-D).
    Lift,
    /// HDBSCAN over the embeddings.
    Group,
    /// Flying pixels, opacity and spatial components.
    Clean,
    /// Points named as another object dropped, and the instance prototypes.
    Semantics,
    /// Window instances into the persistent map.
    Fusion,
    /// The instance list (boxes, names) after the map changed.
    List,
    /// Keyframe window in, map updated: every window stage together.
    Window,
    /// The map snapshot, encoding and publishing of the output topics.
    Publish,
    /// One referring query through the service handler.
    Query,
}

impl Stage {
    pub const ALL: [Stage; 12] = [
        Stage::Ingest,
        Stage::Keyframe,
        Stage::Model,
        Stage::Lift,
        Stage::Group,
        Stage::Clean,
        Stage::Semantics,
        Stage::Fusion,
        Stage::List,
        Stage::Window,
        Stage::Publish,
        Stage::Query,
    ];

    /// The stages of one window pass, in the order they run (fusion included; the list refresh
    /// and publishing are the node's, outside the pass).
    pub const WINDOW_PASS: [Stage; 6] = [
        Stage::Model,
        Stage::Lift,
        Stage::Group,
        Stage::Clean,
        Stage::Semantics,
        Stage::Fusion,
    ];

    /// The stage of a status message's name.
    pub fn from_name(name: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The name in the status message, tracing spans and benchmark CSVs.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Ingest => "ingest",
            Stage::Keyframe => "keyframe",
            Stage::Model => "model",
            Stage::Lift => "lift",
            Stage::Group => "group",
            Stage::Clean => "clean",
            Stage::Semantics => "semantics",
            Stage::Fusion => "fusion",
            Stage::List => "list",
            Stage::Window => "window",
            Stage::Publish => "publish",
            Stage::Query => "query",
        }
    }
}

/// Durations of the stages one pass went through, in the order they ran.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StageTimes(pub Vec<(Stage, Duration)>);

impl StageTimes {
    /// Time `work` as `stage` (also a tracing span, so a subscriber sees the same stages).
    pub fn time<T>(&mut self, stage: Stage, work: impl FnOnce() -> T) -> T {
        let _span = tracing::debug_span!("stage", name = stage.name()).entered();
        let started = Instant::now();
        let out = work();
        self.0.push((stage, started.elapsed()));
        out
    }

    /// The time spent in `stage` (summed when it ran more than once).
    pub fn get(&self, stage: Stage) -> Duration {
        self.0
            .iter()
            .filter(|(s, _)| *s == stage)
            .map(|(_, d)| *d)
            .sum()
    }

    pub fn total(&self) -> Duration {
        self.0.iter().map(|(_, d)| *d).sum()
    }
}

/// Samples kept per stage: enough for a p99 over the last minutes of windows.
pub const RECENT_SAMPLES: usize = 512;

/// Latency summary of one stage over its recent samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageSummary {
    pub stage: Stage,
    /// Samples since the start (the percentiles cover the last [`RECENT_SAMPLES`]).
    pub count: u64,
    pub last_ms: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
}

/// Recent durations per stage.
#[derive(Debug, Clone, Default)]
pub struct StageClock {
    recent: Vec<(Stage, u64, VecDeque<f64>)>,
}

impl StageClock {
    pub fn record(&mut self, stage: Stage, duration: Duration) {
        let millis = duration.as_secs_f64() * 1e3;
        let at = match self.recent.iter().position(|(s, _, _)| *s == stage) {
            Some(at) => at,
            None => {
                self.recent.push((stage, 0, VecDeque::new()));
                self.recent.sort_by_key(|(s, _, _)| *s);
                self.recent
                    .iter()
                    .position(|(s, _, _)| *s == stage)
                    .unwrap_or_default()
            }
        };
        let (_, count, samples) = &mut self.recent[at];
        *count += 1;
        if samples.len() == RECENT_SAMPLES {
            samples.pop_front();
        }
        samples.push_back(millis);
    }

    pub fn record_all(&mut self, times: &StageTimes) {
        for (stage, duration) in &times.0 {
            self.record(*stage, *duration);
        }
    }

    /// One summary per stage that ran, in data-flow order.
    pub fn summary(&self) -> Vec<StageSummary> {
        self.recent
            .iter()
            .filter(|(_, _, samples)| !samples.is_empty())
            .map(|(stage, count, samples)| {
                let mut sorted: Vec<f64> = samples.iter().copied().collect();
                sorted.sort_by(f64::total_cmp);
                StageSummary {
                    stage: *stage,
                    count: *count,
                    last_ms: samples.back().copied().unwrap_or_default(),
                    p50_ms: percentile(&sorted, 0.5),
                    p99_ms: percentile(&sorted, 0.99),
                }
            })
            .collect()
    }
}

/// One summary per stage over every sample of `passes` (an evaluation's whole run), in data-flow
/// order; a stage that ran twice in one pass counts as one sample of their sum.
pub fn summarise(passes: &[StageTimes]) -> Vec<StageSummary> {
    Stage::ALL
        .iter()
        .filter_map(|&stage| {
            let mut samples: Vec<f64> = passes
                .iter()
                .filter(|p| p.0.iter().any(|(s, _)| *s == stage))
                .map(|p| p.get(stage).as_secs_f64() * 1e3)
                .collect();
            let last_ms = *samples.last()?;
            samples.sort_by(f64::total_cmp);
            Some(StageSummary {
                stage,
                count: samples.len() as u64,
                last_ms,
                p50_ms: percentile(&samples, 0.5),
                p99_ms: percentile(&samples, 0.99),
            })
        })
        .collect()
}

/// One line: "p50 280 ms, p99 320 ms over 10 windows (p50/p99 ms per stage: model 85/109, …)".
pub fn describe(stages: &[StageSummary]) -> String {
    let ms = |v: f64| {
        if v < 10.0 {
            format!("{v:.1}")
        } else {
            format!("{v:.0}")
        }
    };
    let parts: Vec<String> = stages
        .iter()
        .filter(|s| s.stage != Stage::Window)
        .map(|s| format!("{} {}/{}", s.stage.name(), ms(s.p50_ms), ms(s.p99_ms)))
        .collect();
    match stages.iter().find(|s| s.stage == Stage::Window) {
        Some(w) => format!(
            "p50 {} ms, p99 {} ms over {} windows (p50/p99 ms per stage: {})",
            ms(w.p50_ms),
            ms(w.p99_ms),
            w.count,
            parts.join(", ")
        ),
        None => format!("no window ran (p50/p99 ms per stage: {})", parts.join(", ")),
    }
}

/// The nearest-rank percentile `q` of ascending `sorted` (0 when empty).
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (q.clamp(0.0, 1.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank_and_empty_is_zero() {
        let sorted: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&sorted, 0.5), 50.0);
        assert_eq!(percentile(&sorted, 0.99), 99.0);
        assert_eq!(percentile(&sorted, 1.0), 100.0);
        assert_eq!(percentile(&sorted, 0.0), 1.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert_eq!(percentile(&[], 0.5), 0.0);
    }

    #[test]
    fn the_clock_summarises_each_stage_in_flow_order_over_its_recent_samples() {
        let mut clock = StageClock::default();
        let ms = |m: u64| Duration::from_millis(m);
        for i in 0..(RECENT_SAMPLES as u64 + 10) {
            clock.record(Stage::Window, ms(if i < 10 { 1000 } else { 100 }));
        }
        let mut times = StageTimes::default();
        times.0.push((Stage::Model, ms(60)));
        times.0.push((Stage::Group, ms(20)));
        times.0.push((Stage::Group, ms(5)));
        assert_eq!(times.get(Stage::Group), ms(25));
        assert_eq!(times.total(), ms(85));
        clock.record_all(&times);
        let summary = clock.summary();
        let stages: Vec<Stage> = summary.iter().map(|s| s.stage).collect();
        assert_eq!(stages, [Stage::Model, Stage::Group, Stage::Window]);
        let window = summary[2];
        assert_eq!(window.count, RECENT_SAMPLES as u64 + 10);
        // The ten slow first windows fell out of the recent samples.
        assert!((window.p99_ms - 100.0).abs() < 1e-9, "{window:?}");
        assert!((summary[1].last_ms - 5.0).abs() < 1e-9);
        assert_eq!(summary[1].count, 2);
    }
}
