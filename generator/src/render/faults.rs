//! The worker's fault-injection test hook: which fault a sample's render attempt gets.

use std::fmt;
use std::str::FromStr;

use super::protocol::Fault;

/// Test hook: `STEREOGEN_FAULT=crash@3,hang@5,crash-always@7,raise@9` makes the worker crash,
/// hang or raise a Python exception on those samples (`crash`/`hang`: first attempt only;
/// `-always`: every attempt; `raise` fails the scene, which is not retried).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FaultPlan(Vec<FaultAt>);

/// One item of a [`FaultPlan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct FaultAt {
    index: u64,
    fault: Fault,
    every_attempt: bool,
}

/// The names of the faults, with whether they hit every attempt.
const FAULT_NAMES: [(&str, Fault, bool); 5] = [
    ("crash", Fault::Crash, false),
    ("hang", Fault::Hang, false),
    ("crash-always", Fault::Crash, true),
    ("hang-always", Fault::Hang, true),
    ("raise", Fault::Raise, false),
];

impl FaultPlan {
    /// The fault to inject into attempt `attempt` (0 first) of sample `index`, if any.
    pub fn fault(&self, index: u64, attempt: u32) -> Option<Fault> {
        self.0
            .iter()
            .find(|f| f.index == index && (f.every_attempt || attempt == 0))
            .map(|f| f.fault)
    }
}

impl FromStr for FaultPlan {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let mut plan = Vec::new();
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (kind, index) = item
                .split_once('@')
                .ok_or_else(|| format!("STEREOGEN_FAULT item {item:?} is not kind@index"))?;
            let index: u64 = index
                .parse()
                .map_err(|_| format!("STEREOGEN_FAULT item {item:?}: bad index"))?;
            let (_, fault, every_attempt) = FAULT_NAMES
                .into_iter()
                .find(|(name, ..)| *name == kind)
                .ok_or_else(|| {
                    format!("STEREOGEN_FAULT: unknown fault {kind:?} (crash, hang, crash-always, hang-always, raise)")
                })?;
            plan.push(FaultAt {
                index,
                fault,
                every_attempt,
            });
        }
        Ok(Self(plan))
    }
}

impl fmt::Display for FaultPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, at) in self.0.iter().enumerate() {
            let (name, ..) = FAULT_NAMES
                .into_iter()
                .find(|(_, fault, every)| *fault == at.fault && *every == at.every_attempt)
                .expect("every fault has a name");
            let sep = if i == 0 { "" } else { "," };
            write!(f, "{sep}{name}@{}", at.index)?;
        }
        Ok(())
    }
}
