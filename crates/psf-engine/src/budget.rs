//! Up-front size checks: what a request would allocate, against the memory this machine
//! has available, so that an oversized request is one clear error that says what it would
//! need, never an allocation failure that aborts the process.

use crate::error::{arg, Result};

const GIB: f64 = 1024.0 * 1024.0 * 1024.0;
/// Requests below this need no look at the memory available.
const SMALL: f64 = 256.0 * 1024.0 * 1024.0;

/// Memory available for new allocations (bytes): Linux's MemAvailable, else 8 GiB.
pub fn available_bytes() -> f64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("MemAvailable:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(8.0 * GIB, |kb| kb * 1024.0)
}

/// A request's allocations: (what, bytes).
pub struct Need(pub Vec<(String, f64)>);

impl Need {
    pub fn total(&self) -> f64 {
        self.0.iter().map(|p| p.1).sum()
    }

    /// An error naming `what` and its largest parts where the total exceeds the memory
    /// available (a non-finite total counts as too large).
    pub fn check(&self, what: &str) -> Result<()> {
        let total = self.total();
        // small requests (every PSF of a batch) skip reading /proc/meminfo
        if total.is_finite() && total <= SMALL {
            return Ok(());
        }
        let avail = available_bytes();
        if total.is_finite() && total <= avail {
            return Ok(());
        }
        let mut parts: Vec<&(String, f64)> = self.0.iter().filter(|p| p.1 > 0.0).collect();
        parts.sort_by(|a, b| b.1.total_cmp(&a.1));
        let list: Vec<String> = parts
            .iter()
            .take(3)
            .map(|(n, b)| format!("{n}: {}", human(*b)))
            .collect();
        arg(format!(
            "{what} would need about {} ({}), more than the {} of memory available",
            human(total),
            list.join(", "),
            human(avail)
        ))
    }
}

/// Bytes as a short human figure.
pub fn human(b: f64) -> String {
    if !b.is_finite() {
        return "more than any machine has".into();
    }
    match b {
        b if b >= 1024.0 * GIB => format!("{:.1} TiB", b / (1024.0 * GIB)),
        b if b >= GIB => format!("{:.1} GiB", b / GIB),
        b => format!("{:.0} MiB", b / (1024.0 * 1024.0)),
    }
}
