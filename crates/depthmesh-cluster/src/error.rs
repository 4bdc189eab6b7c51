//! What can go wrong with a site: the bus, its contents, the map.

use thiserror::Error;

/// An error of a cluster command, saying what and where.
#[derive(Debug, Error)]
pub enum ClusterError {
    /// The bus could not be reached or refused a request.
    #[error("NATS: {0}")]
    Bus(String),
    /// The site's stream or buckets hold something that is not what a
    /// depthmesh site writes there.
    #[error("site {site}: {message}")]
    Site {
        /// The site.
        site: String,
        /// What is wrong.
        message: String,
    },
    /// A library error (a frame that cannot be decoded, a bad setting).
    #[error(transparent)]
    Map(#[from] depthmesh::Error),
}

impl ClusterError {
    /// A failed request to the bus, with what was being done.
    pub fn bus(doing: &str, e: impl std::fmt::Display) -> Self {
        ClusterError::Bus(format!("{doing}: {e}"))
    }

    /// Something wrong in what site `site` holds.
    pub fn site(site: &str, message: impl Into<String>) -> Self {
        ClusterError::Site {
            site: site.to_string(),
            message: message.into(),
        }
    }
}

/// The cluster's result type.
pub type Result<T, E = ClusterError> = std::result::Result<T, E>;
