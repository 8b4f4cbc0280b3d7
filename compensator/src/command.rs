//! What each GCS 2.0 command does to the stage, as far as the compensator is concerned: which
//! commands set a target (and are corrected), which move an axis by other means while
//! compensating (and are refused), which leave a target the proxy no longer knows (and make it
//! forget), which replies carry positions (and are mapped back).
//!
//! The command universe is PI's GCS 2.0 command set as PIPython 2.11 exposes it
//! (`pipython/pidevice/common/gcsbasecommands.py`); the meaning of each command follows PI's own
//! descriptions there (the text of PI's controller manuals). Every command not listed here is
//! forwarded untouched: it neither moves an axis nor changes what a position means. The table is
//! looked up with the mnemonic folded to upper case, because GCS mnemonics are
//! case-insensitive.

use crate::gcs::key;

/// How a move command's arguments set targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveKind {
    /// `MOV {axis target}`: absolute targets.
    Absolute,
    /// `MVR {axis distance}`: targets relative to the current targets.
    Relative,
    /// `MVE {axis target}`: absolute targets reached on a straight path (vector move).
    Vector,
    /// `GOH [{axis}]`: to the home position, which is position 0 ("equivalent to moving the
    /// axes to positions 0 using MOV", PIPython's `GOH`).
    Home,
}

/// Which axes a command that makes the proxy forget targets affects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Affects {
    /// The axis identifiers in the arguments; all axes when there are none (`HLT`, `FRF`).
    Listed,
    /// `{axis value}` pairs (`SVO`, `EAX`): the axes named.
    Paired,
    /// All axes (`STP`, or arguments that are not axes, e.g. `RNP` channels).
    All,
}

/// Why a command is refused while compensating (it moves an axis to a target the model never
/// saw, or changes what the controller's positions mean).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Refused when it names a model axis, or names no axis (then it means all axes):
    /// step/impulse responses, open-loop values, raw targets, jogging, redefining positions.
    ModelAxes,
    /// Refused whatever its arguments: wave generator output, macros, trajectories, scans,
    /// coordinate systems, axis renaming, PiezoWalk open-loop steps (their arguments are
    /// generators, macros or channels, not axes the proxy can check).
    Always,
}

/// What the proxy does with a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Targets corrected by the model.
    Move(MoveKind),
    /// `POS?`/`MOV?`: the reply's positions are mapped back to calibrated coordinates.
    PositionQuery {
        /// `MOV?` (targets): a reply equal to the command the proxy sent maps back exactly.
        target: bool,
    },
    /// Forwarded; the targets of the affected axes are unknown afterwards (stops, referencing,
    /// servo changes: the controller sets its target to where the stage ended up).
    Forget(Affects),
    /// Refused while compensating.
    Refuse(Refusal),
    /// `WGO`, `JON`, `HIN`, `EGE`: `{id value}` pairs that start (any value ≠ 0: refused) or
    /// stop (all values 0: forwarded, all targets forgotten) generator, joystick, HID or gearing
    /// motion.
    StartStop,
    /// `MAC <sub-command>`: `START`, `NSTART`, `BEG`, `DEF` refused; `STOP` forgets all targets.
    Macro,
    /// `PUN` (set the position unit): forwarded, then the unit is read again.
    SetUnit,
    /// `PUN?`: relayed (the proxy reads the units of the model axes with a query of its own,
    /// whatever the host asks).
    UnitQuery,
    /// `CSV?`: relayed; the proxy reads the GCS syntax version in the reply too.
    VersionQuery,
    /// `SAI?`: relayed; the proxy learns the controller's axis identifiers from the reply.
    AxesQuery,
    /// `TMN?`/`TMX?`: relayed (the proxy reads the travel with queries of its own).
    TravelQuery,
    /// `*IDN?` (not in the table: five characters; the proxy compares the word): relayed; its
    /// reply is the controller's identification line, which the proxy's markers bring back.
    IdnQuery,
    /// `ERR?`: answered by the proxy when it has an error of its own.
    ErrorQuery,
    /// `RBT`: the controller restarts; targets, units and version are unknown afterwards.
    Reboot,
    /// Forwarded untouched (a query's reply relayed untouched).
    Pass,
}

use Action::*;
use Affects::*;
use MoveKind::*;
use Refusal::*;

/// Every command the proxy treats specially: a constant key per mnemonic, [`action`] as one
/// `match` on them (a few compares), [`table`] for documentation and tests. A mnemonic listed
/// twice would be an unreachable pattern.
macro_rules! commands {
    ($($(#[$doc:meta])* $name:ident = $word:literal => $action:expr,)*) => {
        $(const $name: u32 = key($word);)*

        /// The action for a command word with [`key`] `k` (see [`crate::gcs::Split::key`]).
        #[deny(unreachable_patterns)]
        pub fn action_of_key(k: u32) -> Action {
            match k {
                $($name => $action,)*
                _ => Pass,
            }
        }

        /// Every mnemonic the proxy treats specially, with its action.
        pub fn table() -> impl Iterator<Item = (&'static [u8], Action)> {
            [$((&$word[..], $action)),*].into_iter()
        }
    };
}

commands! {
    // targets, corrected
    K_MOV = b"MOV" => Move(Absolute),
    K_MVR = b"MVR" => Move(Relative),
    K_MVE = b"MVE" => Move(Vector),
    K_GOH = b"GOH" => Move(Home),
    // replies carrying positions
    K_POS_Q = b"POS?" => PositionQuery { target: false },
    K_MOV_Q = b"MOV?" => PositionQuery { target: true },
    // stops and halts ("after the axes are stopped, their target positions are set to their
    // current positions"), referencing moves, servo and axis enable changes, relaxing
    K_HLT = b"HLT" => Forget(Listed),
    K_STP = b"STP" => Forget(All),
    K_STF = b"STF" => Forget(All),
    K_FRF = b"FRF" => Forget(Listed),
    K_FNL = b"FNL" => Forget(Listed),
    K_FPL = b"FPL" => Forget(Listed),
    K_REF = b"REF" => Forget(Listed),
    K_MNL = b"MNL" => Forget(Listed),
    K_MPL = b"MPL" => Forget(Listed),
    K_FED = b"FED" => Forget(All),
    K_INI = b"INI" => Forget(Listed),
    K_CLR = b"CLR" => Forget(Listed),
    K_SVO = b"SVO" => Forget(Paired),
    K_EAX = b"EAX" => Forget(Paired),
    K_RNP = b"RNP" => Forget(All),
    // raw targets and open-loop motion of the named axes
    K_STE = b"STE" => Refuse(ModelAxes),
    K_IMP = b"IMP" => Refuse(ModelAxes),
    K_SVA = b"SVA" => Refuse(ModelAxes),
    K_SVR = b"SVR" => Refuse(ModelAxes),
    K_SMO = b"SMO" => Refuse(ModelAxes),
    K_OMA = b"OMA" => Refuse(ModelAxes),
    K_OMR = b"OMR" => Refuse(ModelAxes),
    K_CTV = b"CTV" => Refuse(ModelAxes),
    K_CTR = b"CTR" => Refuse(ModelAxes),
    K_MOV_X = b"MOV!" => Refuse(ModelAxes),
    K_JOG = b"JOG" => Refuse(ModelAxes),
    K_POL = b"POL" => Refuse(ModelAxes),
    // what a position means: home, set position, autozero
    K_DFH = b"DFH" => Refuse(ModelAxes),
    K_POS = b"POS" => Refuse(ModelAxes),
    K_ATZ = b"ATZ" => Refuse(ModelAxes),
    // arguments that are channels, generators, trajectories, scans or coordinate systems
    K_OSM = b"OSM" => Refuse(Always),
    K_OAD = b"OAD" => Refuse(Always),
    K_SMV = b"SMV" => Refuse(Always),
    K_TSP = b"TSP" => Refuse(Always),
    K_SAI = b"SAI" => Refuse(Always),
    K_WAV = b"WAV" => Refuse(Always),
    K_WTR = b"WTR" => Refuse(Always),
    K_WOS = b"WOS" => Refuse(Always),
    K_TGA = b"TGA" => Refuse(Always),
    K_TGS = b"TGS" => Refuse(Always),
    K_AAP = b"AAP" => Refuse(Always),
    K_FSA = b"FSA" => Refuse(Always),
    K_FSC = b"FSC" => Refuse(Always),
    K_FSM = b"FSM" => Refuse(Always),
    K_FDR = b"FDR" => Refuse(Always),
    K_FDG = b"FDG" => Refuse(Always),
    K_FAA = b"FAA" => Refuse(Always),
    K_FAM = b"FAM" => Refuse(Always),
    K_FAS = b"FAS" => Refuse(Always),
    K_FIO = b"FIO" => Refuse(Always),
    K_FLM = b"FLM" => Refuse(Always),
    K_FLS = b"FLS" => Refuse(Always),
    K_MRT = b"MRT" => Refuse(Always),
    K_MRW = b"MRW" => Refuse(Always),
    K_SPI = b"SPI" => Refuse(Always),
    K_KEN = b"KEN" => Refuse(Always),
    K_KSD = b"KSD" => Refuse(Always),
    K_KSF = b"KSF" => Refuse(Always),
    K_KST = b"KST" => Refuse(Always),
    K_KSW = b"KSW" => Refuse(Always),
    K_KLF = b"KLF" => Refuse(Always),
    K_KLN = b"KLN" => Refuse(Always),
    K_KSB = b"KSB" => Refuse(Always),
    K_KCP = b"KCP" => Refuse(Always),
    // start or stop generator, joystick, HID, gearing motion
    K_WGO = b"WGO" => StartStop,
    K_JON = b"JON" => StartStop,
    K_HIN = b"HIN" => StartStop,
    K_EGE = b"EGE" => StartStop,
    K_MAC = b"MAC" => Macro,
    // what the proxy reads from the controller
    K_PUN = b"PUN" => SetUnit,
    K_PUN_Q = b"PUN?" => UnitQuery,
    K_CSV_Q = b"CSV?" => VersionQuery,
    K_SAI_Q = b"SAI?" => AxesQuery,
    K_TMN_Q = b"TMN?" => TravelQuery,
    K_TMX_Q = b"TMX?" => TravelQuery,
    K_ERR_Q = b"ERR?" => ErrorQuery,
    K_RBT = b"RBT" => Reboot,
}

/// The action for a command word as sent (any case).
pub fn action(command: &[u8]) -> Action {
    action_of_key(key(command))
}

/// True when a command word is a query (its reply comes back to the host).
pub fn is_query(command: &[u8]) -> bool {
    command.last() == Some(&b'?')
}

/// The action of a `MAC` sub-command (`MAC START m`, `mac nstart m 3`, `MAC BEG m`, …).
pub fn macro_action(sub: &[u8]) -> Action {
    let is = |w: &[u8]| sub.eq_ignore_ascii_case(w);
    if is(b"START") || is(b"NSTART") || is(b"BEG") {
        Refuse(Always)
    } else if is(b"DEF") {
        // the start-up macro runs at the controller's next power-on, unseen by the proxy
        Refuse(Always)
    } else if is(b"STOP") {
        Forget(All)
    } else {
        Pass
    }
}
