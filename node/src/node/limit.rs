//! The bound on requests: a token bucket shared by every service and the JSON API, so a client
//! that floods the node is refused (with the reason, counted) instead of queueing work that
//! starves the window pass of the map's lock.

use std::time::Instant;

/// A token bucket: `rate` requests per second, bursts of up to `rate` (at least 1). A rate of 0
/// admits everything.
#[derive(Debug, Clone)]
pub struct RequestLimiter {
    rate: f64,
    tokens: f64,
    last: Option<Instant>,
}

impl Default for RequestLimiter {
    fn default() -> Self {
        Self::new(0.0)
    }
}

impl RequestLimiter {
    /// `rate` requests per second; 0 (or anything not a positive number) is no bound.
    pub fn new(rate: f64) -> Self {
        let rate = if rate.is_finite() && rate > 0.0 {
            rate
        } else {
            0.0
        };
        Self {
            rate,
            tokens: rate.max(1.0),
            last: None,
        }
    }

    fn burst(&self) -> f64 {
        self.rate.max(1.0)
    }

    /// Whether a request arriving at `now` is taken (it then uses one token).
    pub fn admit(&mut self, now: Instant) -> bool {
        if self.rate == 0.0 {
            return true;
        }
        if let Some(last) = self.last {
            // A clock read out of order (threads) refills nothing rather than going negative.
            let elapsed = now.saturating_duration_since(last).as_secs_f64();
            self.tokens = (self.tokens + elapsed * self.rate).min(self.burst());
        }
        self.last = Some(self.last.map_or(now, |last| last.max(now)));
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[test]
    fn a_burst_is_taken_then_refused_then_the_bucket_refills_at_the_rate() {
        let mut limiter = RequestLimiter::new(10.0);
        let t0 = Instant::now();
        let taken = (0..25).filter(|_| limiter.admit(t0)).count();
        assert_eq!(taken, 10, "a burst of the rate");
        assert!(
            !limiter.admit(t0 + Duration::from_millis(50)),
            "half a token"
        );
        assert!(
            limiter.admit(t0 + Duration::from_millis(100)),
            "one token back"
        );
        // A long pause refills to the burst, not beyond.
        let later = t0 + Duration::from_secs(60);
        let taken = (0..25).filter(|_| limiter.admit(later)).count();
        assert_eq!(taken, 10);
    }

    #[test]
    fn no_bound_and_nonsense_rates_admit_everything_and_a_tiny_rate_still_admits_one() {
        let t0 = Instant::now();
        for rate in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let mut limiter = RequestLimiter::new(rate);
            assert!((0..10_000).all(|_| limiter.admit(t0)), "{rate}");
        }
        let mut slow = RequestLimiter::new(0.01);
        assert!(slow.admit(t0));
        assert!(!slow.admit(t0 + Duration::from_secs(1)));
        assert!(slow.admit(t0 + Duration::from_secs(100)));
        // A clock that steps back refills nothing.
        let mut limiter = RequestLimiter::new(1.0);
        assert!(limiter.admit(t0 + Duration::from_secs(5)));
        assert!(!limiter.admit(t0));
    }
}
