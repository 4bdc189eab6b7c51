//! Riding out a bus that does not answer for a while (a nats-server
//! restarting, a network blip): the loop of a worker or a tracker tries
//! again instead of exiting, for up to [`RIDE_OUT`], and every process
//! says when its connection drops and when it is back.

use crate::error::{ClusterError, Result};
use async_nats::Event;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How long a worker or a tracker keeps trying a bus it cannot reach before
/// it gives up. Its leases expire meanwhile and its shards or sensor may go
/// to others; it takes its share again once the bus is back.
pub const RIDE_OUT: Duration = Duration::from_secs(60);

/// Pause between tries while the bus does not answer.
const PAUSE: Duration = Duration::from_millis(250);

/// The failed requests to the bus since the last turn that went through.
#[derive(Debug, Default)]
pub struct Outage {
    since: Option<Instant>,
}

impl Outage {
    /// Takes what a turn of the loop of `who` gave: a failed request to the
    /// bus is said once and tried again after a pause (`Ok`) until the bus
    /// has not answered for [`RIDE_OUT`]; then, and for any other error, the
    /// error is given back.
    pub async fn after(&mut self, who: &str, turn: Result<()>) -> Result<()> {
        match turn {
            Ok(()) => {
                if let Some(since) = self.since.take() {
                    eprintln!(
                        "{who}: the bus answers again after {:.1} s",
                        since.elapsed().as_secs_f64()
                    );
                }
                Ok(())
            }
            Err(e @ ClusterError::Bus(_)) => {
                let since = *self.since.get_or_insert_with(|| {
                    eprintln!(
                        "{who}: {e}; trying again for up to {} s",
                        RIDE_OUT.as_secs()
                    );
                    Instant::now()
                });
                if since.elapsed() >= RIDE_OUT {
                    return Err(e);
                }
                tokio::time::sleep(PAUSE).await;
                Ok(())
            }
            Err(e) => Err(e),
        }
    }
}

/// What a process says about its connection to the bus.
///
/// A request made while the bus is gone is sent once the connection is
/// back, and answered if that is within its timeout (10 s; 5 s for an
/// acknowledgement), and a worker's heartbeat first waits for the lease
/// keeper's round (see [`crate::keeper`]); so a process can ride out an
/// outage with no request failing and [`Outage`] saying nothing. The
/// client's own events tell every drop and every return of the
/// connection, whatever the process was doing.
#[derive(Debug)]
pub struct ConnectionLog {
    url: String,
    /// When the connection dropped, while it is down.
    lost: Mutex<Option<Instant>>,
}

impl ConnectionLog {
    /// A log of the connection to the bus at `url`.
    pub fn new(url: &str) -> Self {
        ConnectionLog {
            url: url.to_string(),
            lost: Mutex::default(),
        }
    }

    /// What to say about `event`, if anything: a drop, and a return after
    /// one (not the first connection), with how long it was down.
    pub fn on(&self, event: &Event) -> Option<String> {
        let mut lost = self.lost.lock().expect("connection log lock");
        match event {
            Event::Disconnected => {
                lost.get_or_insert_with(Instant::now);
                Some(format!(
                    "the connection to the bus at {} dropped; reconnecting",
                    self.url
                ))
            }
            Event::Connected => lost.take().map(|since| {
                format!(
                    "connected to the bus at {} again after {:.1} s",
                    self.url,
                    since.elapsed().as_secs_f64()
                )
            }),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_connection_log_tells_drops_and_returns_not_the_first_connection() {
        let log = ConnectionLog::new("nats://127.0.0.1:4222");
        assert_eq!(log.on(&Event::Connected), None);
        let dropped = log.on(&Event::Disconnected).unwrap();
        assert!(dropped.contains("127.0.0.1:4222 dropped"), "{dropped}");
        // A second drop while down (a failed reconnect) keeps the first time.
        log.on(&Event::Disconnected);
        let back = log.on(&Event::Connected).unwrap();
        assert!(
            back.starts_with("connected to the bus at nats://127.0.0.1:4222 again after 0.0 s"),
            "{back}"
        );
        assert_eq!(log.on(&Event::Connected), None);
        assert_eq!(log.on(&Event::Closed), None);
    }
}
