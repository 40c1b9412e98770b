//! Capped exponential backoff with jitter, for reconnecting to a server that is away.

use std::time::Duration;

/// Exponential backoff with ±20 % jitter: `initial`, 2·`initial`, 4·`initial`, ... up to `max`.
#[derive(Clone, Debug)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    current: Option<Duration>,
}

impl Backoff {
    /// A backoff that starts at `initial` and never waits longer than `max`.
    pub fn new(initial: Duration, max: Duration) -> Self {
        Self {
            initial,
            max: max.max(initial),
            current: None,
        }
    }

    /// Forget the failures: the next delay is `initial` again.
    pub fn reset(&mut self) {
        self.current = None;
    }

    /// The delay before the next attempt, without jitter.
    pub fn next_base(&mut self) -> Duration {
        let next = match self.current {
            None => self.initial,
            Some(d) => (d * 2).min(self.max),
        };
        self.current = Some(next);
        next
    }

    /// The delay before the next attempt, with jitter so that many displays do not reconnect in step.
    pub fn next_delay(&mut self) -> Duration {
        let base = self.next_base();
        base.mul_f64(0.8 + 0.4 * rand::random::<f64>()).min(self.max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backoff_doubles_up_to_its_cap_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(500));
        let delays: Vec<u128> = (0..5).map(|_| b.next_base().as_millis()).collect();
        assert_eq!(delays, vec![100, 200, 400, 500, 500]);
        b.reset();
        assert_eq!(b.next_base(), Duration::from_millis(100));
        // Jitter stays within ±20 % and never exceeds the cap.
        for _ in 0..100 {
            let d = b.next_delay();
            assert!(
                d >= Duration::from_millis(80) && d <= Duration::from_millis(500),
                "{d:?}"
            );
        }
    }
}
