//! When a dead process is started again: after a backoff that doubles with each death in the window, at most
//! `max_restarts` times within `window_s`; the death after those restarts (death `max_restarts + 1` in the window, OTP's
//! restart intensity) is a crash loop, which ends the run. Pure logic, tested without processes.

use cabc_proto::config::SupervisionSection;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// What to do about a death.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Decision {
    /// Start it again after this wait.
    Restart(Duration),
    /// It died `deaths` times within the window: a crash loop; the run stops.
    GiveUp { deaths: usize },
}

/// One process's deaths in the window, and the policy they are judged by.
#[derive(Clone, Debug)]
pub struct Deaths {
    policy: SupervisionSection,
    at: VecDeque<Instant>,
}

impl Deaths {
    pub fn new(policy: &SupervisionSection) -> Self {
        Deaths {
            policy: policy.clone(),
            at: VecDeque::new(),
        }
    }

    /// Records a death at `now` and decides.
    pub fn died(&mut self, now: Instant) -> Decision {
        let window = Duration::from_secs_f64(self.policy.window_s);
        while self
            .at
            .front()
            .is_some_and(|&t| now.duration_since(t) >= window)
        {
            self.at.pop_front();
        }
        self.at.push_back(now);
        let deaths = self.at.len();
        if deaths > self.policy.max_restarts as usize {
            return Decision::GiveUp { deaths };
        }
        let doublings = (deaths - 1).min(30) as i32;
        let wait = (self.policy.backoff_s * 2f64.powi(doublings)).min(self.policy.backoff_max_s);
        Decision::Restart(Duration::from_secs_f64(wait.max(0.0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(max_restarts: u32) -> SupervisionSection {
        SupervisionSection {
            max_restarts,
            window_s: 60.0,
            backoff_s: 1.0,
            backoff_max_s: 5.0,
        }
    }

    #[test]
    fn the_backoff_doubles_with_each_death_in_the_window_up_to_its_cap() {
        let t0 = Instant::now();
        let mut d = Deaths::new(&policy(10));
        let waits: Vec<_> = (0..5)
            .map(|i| d.died(t0 + Duration::from_secs(i)))
            .collect();
        let s = Duration::from_secs;
        assert_eq!(
            waits,
            vec![
                Decision::Restart(s(1)),
                Decision::Restart(s(2)),
                Decision::Restart(s(4)),
                Decision::Restart(s(5)),
                Decision::Restart(s(5)),
            ]
        );
    }

    #[test]
    fn deaths_out_of_the_window_are_forgotten() {
        let t0 = Instant::now();
        let mut d = Deaths::new(&policy(2));
        assert_eq!(d.died(t0), Decision::Restart(Duration::from_secs(1)));
        assert_eq!(
            d.died(t0 + Duration::from_secs(30)),
            Decision::Restart(Duration::from_secs(2))
        );
        // The first death is 60 s old: out of the window, so this is the second death in it, not the third.
        assert_eq!(
            d.died(t0 + Duration::from_secs(60)),
            Decision::Restart(Duration::from_secs(2))
        );
    }

    #[test]
    fn a_process_that_keeps_dying_is_given_up() {
        let t0 = Instant::now();
        let mut d = Deaths::new(&policy(3));
        for i in 0..3 {
            assert!(matches!(
                d.died(t0 + Duration::from_secs(i)),
                Decision::Restart(_)
            ));
        }
        assert_eq!(
            d.died(t0 + Duration::from_secs(3)),
            Decision::GiveUp { deaths: 4 }
        );
        // max_restarts = 0: never restarted.
        let mut never = Deaths::new(&policy(0));
        assert_eq!(never.died(t0), Decision::GiveUp { deaths: 1 });
    }
}
