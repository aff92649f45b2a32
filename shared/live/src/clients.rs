//! What the server keeps of each client: the rate it asked for, the
//! channels it is subscribed to and whether it gave the token. Pure
//! bookkeeping, keyed by any client id, so that it is tested without a
//! socket. A client is known from its admission (the gate's mark, the first
//! message of a connection that came through the gate) until its
//! connection ends; nothing is kept of one that was never admitted.
//!
//! A client's rate is `live.rate_hz`, a parameter of its own: 10 kHz cannot
//! be drawn in a browser, so a client names the rate it wants and gets
//! every N-th sample (the samples whose sequence number N divides, the same
//! on every channel and in every client, so decimated streams line up with
//! each other and with the sample file).

use std::collections::{BTreeSet, HashMap};
use std::hash::Hash;

/// The parameter a client names its rate by.
pub const RATE_PARAMETER: &str = "live.rate_hz";
/// The parameter a client gives the token by (when the server needs one).
pub const TOKEN_PARAMETER: &str = "live.token";

/// Where one client's messages go and which of them: a copy of the table
/// the reader takes when the table changes, so that it never holds the
/// table's lock while it hands messages to the server.
#[derive(Debug, Clone, PartialEq)]
pub struct Route<S> {
    pub sink: S,
    pub every: u64,
    pub channels: BTreeSet<u64>,
}

/// Where a message of `channel` with sequence number `seq` goes, into `out`
/// (cleared first): every subscribed client whose rate keeps it.
pub fn targets<S: Copy>(routes: &[Route<S>], channel: u64, seq: u64, out: &mut Vec<S>) {
    out.clear();
    out.extend(
        routes
            .iter()
            .filter(|r| r.channels.contains(&channel) && seq.is_multiple_of(r.every))
            .map(|r| r.sink),
    );
}

#[derive(Debug, Clone)]
struct ClientState<S> {
    sink: Option<S>,
    every: u64,
    channels: BTreeSet<u64>,
    token_given: bool,
}

impl<S> Default for ClientState<S> {
    fn default() -> Self {
        Self {
            sink: None,
            every: 1,
            channels: BTreeSet::new(),
            token_given: false,
        }
    }
}

/// Every client's state. `K` is the client's id, `S` where its messages go.
#[derive(Debug)]
pub struct ClientTable<K, S> {
    loop_rate_hz: f64,
    clients: HashMap<K, ClientState<S>>,
    version: u64,
}

impl<K: Eq + Hash + Copy, S: Copy> ClientTable<K, S> {
    pub fn new(loop_rate_hz: f64) -> Self {
        Self {
            loop_rate_hz,
            clients: HashMap::new(),
            version: 0,
        }
    }

    /// `client` is one of the server's (its connection came through the gate).
    pub fn admit(&mut self, client: K) {
        self.clients.entry(client).or_default();
        self.version += 1;
    }

    pub fn admitted(&self, client: K) -> bool {
        self.clients.contains_key(&client)
    }

    /// `client`'s connection ended: its rate, token and subscriptions go.
    pub fn forget(&mut self, client: K) {
        if self.clients.remove(&client).is_some() {
            self.version += 1;
        }
    }

    /// Clients admitted and not yet gone.
    pub fn len(&self) -> usize {
        self.clients.len()
    }

    pub fn is_empty(&self) -> bool {
        self.clients.is_empty()
    }

    /// `client` subscribed to `channel`; its messages go to `sink`. Nothing
    /// for a client that was not admitted (or has gone).
    pub fn subscribed(&mut self, client: K, sink: S, channel: u64) -> bool {
        let Some(state) = self.clients.get_mut(&client) else {
            return false;
        };
        state.sink = Some(sink);
        state.channels.insert(channel);
        self.version += 1;
        true
    }

    /// `client` unsubscribed from `channel` (also when it disconnects: the
    /// server unsubscribes a leaving client from everything). Its rate and
    /// token stay while it is connected.
    pub fn unsubscribed(&mut self, client: K, channel: u64) {
        if let Some(state) = self.clients.get_mut(&client) {
            state.channels.remove(&channel);
            self.version += 1;
        }
    }

    /// Sets `client`'s rate: the loop's rate divided by a whole number.
    /// Returns the rate it gets.
    pub fn set_rate(&mut self, client: K, rate_hz: f64) -> Result<f64, String> {
        let every = decimation(self.loop_rate_hz, rate_hz)?;
        let state = self
            .clients
            .get_mut(&client)
            .ok_or_else(|| format!("{RATE_PARAMETER}: not a client of this server"))?;
        state.every = every;
        self.version += 1;
        Ok(self.loop_rate_hz / every as f64)
    }

    /// The rate `client` gets (the loop's until it names another).
    pub fn rate_hz(&self, client: K) -> f64 {
        let every = self.clients.get(&client).map_or(1, |c| c.every);
        self.loop_rate_hz / every as f64
    }

    pub fn give_token(&mut self, client: K) {
        if let Some(state) = self.clients.get_mut(&client) {
            state.token_given = true;
        }
    }

    pub fn token_given(&self, client: K) -> bool {
        self.clients.get(&client).is_some_and(|c| c.token_given)
    }

    /// Changes with every subscription and rate: a reader's copy of the
    /// routes is current while this is the number it was taken at.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Every subscribed client's route, into `out` (cleared first).
    pub fn routes(&self, out: &mut Vec<Route<S>>) {
        out.clear();
        out.extend(self.clients.values().filter_map(|c| {
            let sink = c.sink.filter(|_| !c.channels.is_empty());
            sink.map(|sink| Route {
                sink,
                every: c.every,
                channels: c.channels.clone(),
            })
        }));
    }

    /// Clients with at least one subscription.
    pub fn subscribed_clients(&self) -> usize {
        self.clients
            .values()
            .filter(|c| !c.channels.is_empty())
            .count()
    }
}

/// How many samples of a loop at `loop_rate_hz` make one at `rate_hz`:
/// the rate must divide the loop's (so that the kept samples are the same
/// every time), and be positive and no faster than the loop.
pub fn decimation(loop_rate_hz: f64, rate_hz: f64) -> Result<u64, String> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(format!(
            "{RATE_PARAMETER}: {rate_hz} is not a positive rate in Hz"
        ));
    }
    if rate_hz > loop_rate_hz {
        return Err(format!(
            "{RATE_PARAMETER}: {rate_hz} Hz is faster than the loop's {loop_rate_hz} Hz"
        ));
    }
    // At least one sample a minute: a rate of 1e-300 Hz was accepted and
    // sent nothing, ever.
    if rate_hz < 1.0 / 60.0 {
        return Err(format!(
            "{RATE_PARAMETER}: {rate_hz} Hz is slower than one sample a minute"
        ));
    }
    let every = (loop_rate_hz / rate_hz).round();
    if ((loop_rate_hz / every) - rate_hz).abs() > 1e-9 * loop_rate_hz {
        return Err(format!(
            "{RATE_PARAMETER}: {rate_hz} Hz does not divide the loop's {loop_rate_hz} Hz; \
             name {loop_rate_hz}/N Hz (e.g. {} or {})",
            loop_rate_hz / every,
            loop_rate_hz / (every + 1.0)
        ));
    }
    Ok(every as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rate_slower_than_one_sample_a_minute_is_refused() {
        assert!(decimation(10_000.0, 1e-300).is_err());
        assert!(decimation(10_000.0, 0.01).is_err());
        assert_eq!(decimation(10_000.0, 1.0), Ok(10_000));
    }

    #[test]
    fn a_rate_must_divide_the_loops() {
        assert_eq!(decimation(10_000.0, 10_000.0), Ok(1));
        assert_eq!(decimation(10_000.0, 100.0), Ok(100));
        assert_eq!(decimation(10_000.0, 2_500.0), Ok(4));
        let err = decimation(10_000.0, 300.0).unwrap_err();
        assert!(
            err.contains("does not divide") && err.contains("live.rate_hz"),
            "{err}"
        );
        assert!(
            decimation(10_000.0, 20_000.0)
                .unwrap_err()
                .contains("faster")
        );
        assert!(decimation(10_000.0, 0.0).is_err());
        assert!(decimation(10_000.0, f64::NAN).is_err());
    }

    #[test]
    fn each_client_gets_its_own_rate_on_the_same_samples() {
        let mut table = ClientTable::<u32, char>::new(10_000.0);
        table.admit(1);
        table.admit(2);
        table.subscribed(1, 'a', 7);
        table.subscribed(2, 'b', 7);
        table.subscribed(2, 'b', 8);
        assert_eq!(table.set_rate(2, 1_000.0), Ok(1_000.0));
        let mut routes = Vec::new();
        table.routes(&mut routes);
        let mut out = Vec::new();
        targets(&routes, 7, 10, &mut out);
        out.sort_unstable();
        assert_eq!(out, ['a', 'b']);
        targets(&routes, 7, 11, &mut out);
        assert_eq!(out, ['a']);
        targets(&routes, 8, 11, &mut out);
        assert!(out.is_empty());
        targets(&routes, 8, 20, &mut out);
        assert_eq!(out, ['b']);
        assert_eq!(table.rate_hz(1), 10_000.0);
        assert_eq!(table.rate_hz(2), 1_000.0);
    }

    #[test]
    fn a_rate_named_before_subscribing_holds_and_a_leaving_client_is_forgotten() {
        let mut table = ClientTable::<u32, char>::new(10_000.0);
        table.admit(3);
        table.set_rate(3, 100.0).unwrap();
        table.give_token(3);
        let before = table.version();
        table.subscribed(3, 'c', 7);
        assert_ne!(table.version(), before);
        let mut routes = Vec::new();
        table.routes(&mut routes);
        let mut out = Vec::new();
        targets(&routes, 7, 50, &mut out);
        assert!(out.is_empty());
        targets(&routes, 7, 100, &mut out);
        assert_eq!(out, ['c']);
        assert!(table.token_given(3));
        assert_eq!(table.subscribed_clients(), 1);
        // Unsubscribed from all: no route, its rate and token kept while
        // it is connected.
        table.unsubscribed(3, 7);
        assert_eq!(table.subscribed_clients(), 0);
        table.routes(&mut routes);
        assert!(routes.is_empty());
        assert!(table.token_given(3));
        assert_eq!(table.rate_hz(3), 100.0);
        // Gone: forgotten.
        table.forget(3);
        assert!(!table.admitted(3));
        assert!(!table.token_given(3));
        assert_eq!(table.rate_hz(3), 10_000.0);
        assert!(table.is_empty());
    }

    #[test]
    fn nothing_is_kept_of_a_client_that_was_not_admitted() {
        let mut table = ClientTable::<u32, char>::new(10_000.0);
        assert!(!table.subscribed(9, 'z', 7));
        assert!(table.set_rate(9, 100.0).is_err());
        table.give_token(9);
        assert!(!table.token_given(9));
        let mut routes = Vec::new();
        table.routes(&mut routes);
        assert!(routes.is_empty());
        assert_eq!(table.len(), 0);
    }

    #[test]
    fn a_refused_rate_leaves_the_old_one() {
        let mut table = ClientTable::<u32, char>::new(10_000.0);
        table.admit(1);
        table.set_rate(1, 500.0).unwrap();
        assert!(table.set_rate(1, 333.0).is_err());
        assert_eq!(table.rate_hz(1), 500.0);
    }
}
