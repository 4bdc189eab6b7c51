//! Riding out a bus that does not answer for a while (a nats-server
//! restarting, a network blip): the loop of a worker or a tracker tries
//! again instead of exiting, for up to [`RIDE_OUT`].

use crate::error::{ClusterError, Result};
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
