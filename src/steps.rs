//! How many rays the next step of a long pick takes. The server answers a pick in steps and
//! asks between them whether its client still waits and whether the request's work limit is
//! passed (`server::steps`); Python answers in batches and runs the interpreter's signal
//! handlers between them, so Ctrl-C stops a pick. Both want steps long enough that picking does
//! not slow down and short enough that the question comes soon, on scenes where a ray costs
//! anything from 50 ns to milliseconds; [`StepSizer`] is that one policy.
//!
//! After each step the next is sized to take about the target time at the cost per ray just
//! seen, but to at most twice the step just taken: a step of cheap rays (misses) followed by
//! costly ones must not become one step of minutes. It shrinks at once when rays cost more.
//! Each ray's answer does not depend on the rays beside it, so the steps never change an answer.

use std::time::Duration;

/// The rays of each next step (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct StepSizer {
    next: usize,
    fewest: usize,
    most: usize,
    target: Duration,
}

impl StepSizer {
    /// Steps of `first` rays first, then sized to take about `target`, each within
    /// `fewest..=most` (`most` at least 1; `fewest` and `first` brought within it).
    pub fn new(first: usize, fewest: usize, most: usize, target: Duration) -> Self {
        let most = most.max(1);
        let fewest = fewest.clamp(1, most);
        Self {
            next: first.clamp(fewest, most),
            fewest,
            most,
            target,
        }
    }

    /// The rays of the next step.
    pub fn next(&self) -> usize {
        self.next
    }

    /// The most rays in any step.
    pub fn most(&self) -> usize {
        self.most
    }

    /// After a step of `rays` rays that took `time`: the next takes about the target time at
    /// that cost per ray, at most twice `rays`.
    pub fn took(&mut self, rays: usize, time: Duration) {
        let rays = rays.max(1);
        let per_ray = time.as_secs_f64() / rays as f64;
        // A float past usize (no time measured) saturates.
        let fit = (self.target.as_secs_f64() / per_ray) as usize;
        self.next = fit
            .min(rays.saturating_mul(2))
            .clamp(self.fewest, self.most);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn steps_grow_at_most_twofold_and_shrink_to_the_target_time_at_once() {
        let mut s = StepSizer::new(256, 256, 1 << 18, 100 * MS);
        assert_eq!(s.next(), 256);
        // Cheap rays: twice the step each time, never past the most.
        for want in [512, 1024, 2048] {
            s.took(s.next(), Duration::from_micros(10));
            assert_eq!(s.next(), want);
        }
        for _ in 0..20 {
            s.took(s.next(), Duration::ZERO);
        }
        assert_eq!(s.next(), 1 << 18);
        // Rays of 1 ms each: 100 of them fit the target, but no fewer than 256.
        s.took(s.next(), (1 << 18) * MS);
        assert_eq!(s.next(), 256);
        // Rays of 0.1 ms: 1,000 fit, but the step grows at most twofold from 256.
        s.took(256, Duration::from_micros(25_600));
        assert_eq!(s.next(), 512);
        s.took(512, Duration::from_micros(51_200));
        assert_eq!(s.next(), 1000);
        // Slower again: shrinks at once to what fits.
        s.took(1000, 400 * MS);
        assert_eq!(s.next(), 256);
    }

    #[test]
    fn bounds_are_kept_whatever_they_are_given() {
        let s = StepSizer::new(4096, 256, 100, 100 * MS);
        assert_eq!((s.next(), s.most()), (100, 100));
        let mut s = StepSizer::new(0, 0, 0, 100 * MS);
        assert_eq!(s.next(), 1);
        s.took(0, Duration::ZERO);
        assert_eq!(s.next(), 1);
        let mut s = StepSizer::new(8, 4, 64, Duration::ZERO);
        s.took(8, MS);
        assert_eq!(s.next(), 4);
    }
}
