//! What the live server exposes and to whom: loopback only unless asked,
//! and then parameter changes need a token given at start (or none are
//! allowed at all).

use std::fmt;
use std::net::SocketAddr;

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
}

impl fmt::Display for OptionsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OptionsError::RemoteNotAllowed(a) => write!(
                f,
                "--live {a}: not a loopback address; serving the loop beyond this machine \
                 takes --live-remote (with --live-token TOKEN or --live-read-only)"
            ),
            OptionsError::RemoteWithoutToken(a) => write!(
                f,
                "--live {a} --live-remote: changes of the loop from another machine need \
                 --live-token TOKEN (clients set the parameter live.token to it), or \
                 --live-read-only"
            ),
            OptionsError::EmptyToken => f.write_str("--live-token: the token is empty"),
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
        if token.as_deref().is_some_and(str::is_empty) {
            return Err(OptionsError::EmptyToken);
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

    #[test]
    fn loopback_needs_nothing_and_another_address_needs_a_flag_and_a_token() {
        assert!(LiveOptions::checked(addr(DEFAULT_ADDRESS), false, None, false).is_ok());
        assert!(LiveOptions::checked(addr("[::1]:9000"), false, None, false).is_ok());
        let remote = addr("0.0.0.0:8765");
        assert_eq!(
            LiveOptions::checked(remote, false, Some("t".into()), false),
            Err(OptionsError::RemoteNotAllowed(remote))
        );
        assert_eq!(
            LiveOptions::checked(remote, true, None, false),
            Err(OptionsError::RemoteWithoutToken(remote))
        );
        assert!(LiveOptions::checked(remote, true, Some("t".into()), false).is_ok());
        assert!(LiveOptions::checked(remote, true, None, true).is_ok());
        assert_eq!(
            LiveOptions::checked(addr(DEFAULT_ADDRESS), false, Some(String::new()), false),
            Err(OptionsError::EmptyToken)
        );
        let text = OptionsError::RemoteNotAllowed(remote).to_string();
        assert!(text.contains("--live-remote"), "{text}");
    }
}
