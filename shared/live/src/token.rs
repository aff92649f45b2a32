//! The token a client gives before it changes the loop (`live.token`):
//! compared in constant time, its failures throttled for the whole server.
//!
//! After [`FREE_FAILURES`] wrong tokens, every further attempt, from any
//! client, is refused unexamined for a lockout that starts at
//! [`FIRST_LOCKOUT`] and doubles with each wrong token after it, up to
//! [`LONGEST_LOCKOUT`]. Over a server's life of T seconds at most about
//! `FREE_FAILURES + 1 + log2(1 + T)` tokens are compared in the first
//! minutes, one a minute after: a guess of a 16-character token is hopeless.
//! The throttle is one for all clients (behind the gate every client comes
//! from the same address); whoever floods it locks the token out for
//! everyone for at most a minute at a time, which a client holding one of
//! the 16 connections could do anyway.

use std::time::{Duration, Instant};

/// The shortest token a server starts with.
pub const MIN_TOKEN_CHARS: usize = 16;
/// Wrong tokens before the first lockout.
pub const FREE_FAILURES: u64 = 5;
pub const FIRST_LOCKOUT: Duration = Duration::from_secs(1);
pub const LONGEST_LOCKOUT: Duration = Duration::from_secs(60);

/// Whether `given` is `token`, in a time that depends on the token's length
/// and the given one's, never on their contents or on where they differ
/// (the given bytes are laid over a buffer of the token's length first, so
/// the comparison itself does not end early on a length that differs).
pub fn matches(token: &str, given: &[u8]) -> bool {
    let token = token.as_bytes();
    let mut candidate = vec![0u8; token.len()];
    for (c, g) in candidate.iter_mut().zip(given) {
        *c = *g;
    }
    let same = constant_time_eq::constant_time_eq(&candidate, token);
    same & (given.len() == token.len())
}

/// What became of one attempt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attempt {
    /// The right token.
    Accepted,
    /// A wrong one, compared and counted; `lockout`: attempts are now
    /// refused for this long.
    Wrong { failures: u64, lockout: Duration },
    /// Not compared: a lockout holds for this much longer.
    Throttled { left: Duration },
}

/// The server's count of wrong tokens and its lockout.
#[derive(Debug, Default)]
pub struct Throttle {
    failures: u64,
    throttled: u64,
    until: Option<Instant>,
}

impl Throttle {
    /// One attempt at `now`: compared (by `check`) unless a lockout holds.
    pub fn attempt(&mut self, now: Instant, check: impl FnOnce() -> bool) -> Attempt {
        if let Some(until) = self.until.filter(|u| now < *u) {
            self.throttled += 1;
            return Attempt::Throttled { left: until - now };
        }
        if check() {
            return Attempt::Accepted;
        }
        self.failures += 1;
        let lockout = lockout_after(self.failures);
        self.until = (!lockout.is_zero()).then(|| now + lockout);
        Attempt::Wrong {
            failures: self.failures,
            lockout,
        }
    }

    /// Wrong tokens compared so far.
    pub fn failures(&self) -> u64 {
        self.failures
    }

    /// Attempts refused unexamined during a lockout.
    pub fn throttled(&self) -> u64 {
        self.throttled
    }
}

/// The lockout after the `failures`-th wrong token.
pub fn lockout_after(failures: u64) -> Duration {
    if failures < FREE_FAILURES {
        return Duration::ZERO;
    }
    let doublings = (failures - FREE_FAILURES).min(16) as u32;
    FIRST_LOCKOUT
        .saturating_mul(1 << doublings)
        .min(LONGEST_LOCKOUT)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_token_itself_matches() {
        let token = "0123456789abcdef";
        assert!(matches(token, token.as_bytes()));
        assert!(!matches(token, b"0123456789abcdeF"));
        assert!(!matches(token, b"0123456789abcde"));
        assert!(!matches(token, b"0123456789abcdef0"));
        assert!(!matches(token, b""));
        // The token's prefix laid over zeros is not the token either.
        assert!(!matches("abc\0", b"abc"));
    }

    #[test]
    fn wrong_tokens_lock_every_attempt_out_for_a_growing_while() {
        let start = Instant::now();
        let mut t = Throttle::default();
        for n in 1..FREE_FAILURES {
            assert_eq!(
                t.attempt(start, || false),
                Attempt::Wrong {
                    failures: n,
                    lockout: Duration::ZERO
                }
            );
        }
        assert_eq!(
            t.attempt(start, || false),
            Attempt::Wrong {
                failures: FREE_FAILURES,
                lockout: FIRST_LOCKOUT
            }
        );
        // Locked out: not even the right token is compared.
        let mut compared = false;
        let half = start + FIRST_LOCKOUT / 2;
        assert_eq!(
            t.attempt(half, || {
                compared = true;
                true
            }),
            Attempt::Throttled {
                left: FIRST_LOCKOUT / 2
            }
        );
        assert!(!compared);
        assert_eq!(t.throttled(), 1);
        // After it, one more wrong token doubles it.
        let after = start + FIRST_LOCKOUT;
        assert_eq!(
            t.attempt(after, || false),
            Attempt::Wrong {
                failures: FREE_FAILURES + 1,
                lockout: 2 * FIRST_LOCKOUT
            }
        );
        // And the right one is taken once it is over.
        assert_eq!(
            t.attempt(after + 2 * FIRST_LOCKOUT, || true),
            Attempt::Accepted
        );
        assert_eq!(t.failures(), FREE_FAILURES + 1);
    }

    #[test]
    fn a_brute_force_gets_a_handful_of_guesses_then_one_a_minute() {
        let start = Instant::now();
        let mut t = Throttle::default();
        // A guess every millisecond for ten minutes.
        for ms in 0..600_000u64 {
            t.attempt(start + Duration::from_millis(ms), || false);
        }
        // 5 free, then after 1, 2, 4, 8, 16, 32 s, then every 60 s.
        assert!(t.failures() <= FREE_FAILURES + 6 + 10, "{}", t.failures());
        assert_eq!(t.failures() + t.throttled(), 600_000);
        assert_eq!(lockout_after(100), LONGEST_LOCKOUT);
        assert_eq!(lockout_after(u64::MAX), LONGEST_LOCKOUT);
    }
}
