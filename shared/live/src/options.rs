//! What the live server exposes and to whom: loopback only unless asked,
//! and then parameter changes need a token given at start (or none are
//! allowed at all). A token has at least [`MIN_TOKEN_CHARS`] characters;
//! `up` takes it from the environment or a file, never its command line
//! (which every local user can read in /proc/PID/cmdline).

use std::fmt;
use std::net::SocketAddr;

pub use crate::token::MIN_TOKEN_CHARS;

/// Where `up` takes the token from (and the server process too: `up` hands
/// it over in the server's environment).
pub const TOKEN_ENV: &str = "FLEXLOOP_LIVE_TOKEN";
/// How to give a token, for messages.
pub const HOW_TO_GIVE_A_TOKEN: &str = "give it in the environment (FLEXLOOP_LIVE_TOKEN=...) \
     or in a file (--live-token-file PATH)";

/// Where the server listens by default: Foxglove's own default port, on
/// loopback.
pub const DEFAULT_ADDRESS: &str = "127.0.0.1:8765";

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveOptions {
    pub address: SocketAddr,
    /// A client must set `live.token` to this before any change of the loop.
    pub token: Option<String>,
    /// Every change of the loop is refused.
    pub read_only: bool,
}

/// A live server that would expose more than it was asked to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OptionsError {
    /// Another address than loopback without `--live-remote`.
    RemoteNotAllowed(SocketAddr),
    /// Another address without a token, and changes allowed.
    RemoteWithoutToken(SocketAddr),
    /// An empty token.
    EmptyToken,
    /// A token shorter than [`MIN_TOKEN_CHARS`] (its length).
    ShortToken(usize),
}

impl fmt::Display for OptionsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OptionsError::RemoteNotAllowed(a) => write!(
                f,
                "--live {a}: not a loopback address; serving the loop beyond this machine \
                 takes --live-remote (with a token, {TOKEN_ENV} or --live-token-file PATH, \
                 or --live-read-only)"
            ),
            OptionsError::RemoteWithoutToken(a) => write!(
                f,
                "--live {a} --live-remote: changes of the loop from another machine need \
                 a token (clients set the parameter live.token to it): {HOW_TO_GIVE_A_TOKEN}; \
                 or --live-read-only"
            ),
            OptionsError::EmptyToken => f.write_str("the live token is empty"),
            OptionsError::ShortToken(n) => write!(
                f,
                "the live token has {n} characters, fewer than the {MIN_TOKEN_CHARS} it needs \
                 (e.g. `openssl rand -hex 16`)"
            ),
        }
    }
}

impl std::error::Error for OptionsError {}

impl LiveOptions {
    /// The options, checked: loopback, or another address with
    /// `allow_remote` and a token or read-only.
    pub fn checked(
        address: SocketAddr,
        allow_remote: bool,
        token: Option<String>,
        read_only: bool,
    ) -> Result<Self, OptionsError> {
        if let Some(token) = &token {
            let n = token.chars().count();
            if n == 0 {
                return Err(OptionsError::EmptyToken);
            }
            if n < MIN_TOKEN_CHARS {
                return Err(OptionsError::ShortToken(n));
            }
        }
        if !address.ip().is_loopback() {
            if !allow_remote {
                return Err(OptionsError::RemoteNotAllowed(address));
            }
            if token.is_none() && !read_only {
                return Err(OptionsError::RemoteWithoutToken(address));
            }
        }
        Ok(Self {
            address,
            token,
            read_only,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(text: &str) -> SocketAddr {
        text.parse().unwrap()
    }

    const TOKEN: &str = "0123456789abcdef";

    #[test]
    fn loopback_needs_nothing_and_another_address_needs_a_flag_and_a_token() {
        assert!(LiveOptions::checked(addr(DEFAULT_ADDRESS), false, None, false).is_ok());
        assert!(LiveOptions::checked(addr("[::1]:9000"), false, None, false).is_ok());
        let remote = addr("0.0.0.0:8765");
        assert_eq!(
            LiveOptions::checked(remote, false, Some(TOKEN.into()), false),
            Err(OptionsError::RemoteNotAllowed(remote))
        );
        assert_eq!(
            LiveOptions::checked(remote, true, None, false),
            Err(OptionsError::RemoteWithoutToken(remote))
        );
        assert!(LiveOptions::checked(remote, true, Some(TOKEN.into()), false).is_ok());
        assert!(LiveOptions::checked(remote, true, None, true).is_ok());
        assert_eq!(
            LiveOptions::checked(addr(DEFAULT_ADDRESS), false, Some(String::new()), false),
            Err(OptionsError::EmptyToken)
        );
        let text = OptionsError::RemoteNotAllowed(remote).to_string();
        assert!(text.contains("--live-remote"), "{text}");
        let text = OptionsError::RemoteWithoutToken(remote).to_string();
        assert!(
            text.contains(TOKEN_ENV) && text.contains("--live-token-file"),
            "{text}"
        );
    }

    #[test]
    fn a_short_token_is_refused_before_anything_starts() {
        let local = addr(DEFAULT_ADDRESS);
        let short = "x".repeat(MIN_TOKEN_CHARS - 1);
        assert_eq!(
            LiveOptions::checked(local, false, Some(short), false),
            Err(OptionsError::ShortToken(MIN_TOKEN_CHARS - 1))
        );
        // Characters, not bytes.
        let accented = "é".repeat(MIN_TOKEN_CHARS - 1);
        assert!(LiveOptions::checked(local, false, Some(accented), false).is_err());
        assert!(LiveOptions::checked(local, false, Some(TOKEN.into()), false).is_ok());
        let text = OptionsError::ShortToken(4).to_string();
        assert!(text.contains("16"), "{text}");
    }
}
