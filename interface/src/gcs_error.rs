//! The GCS error codes the compensator answers itself, on the host's next `ERR?`, when it
//! refuses a line (nothing is forwarded to the controller).
//!
//! Four are PI's own codes with PI's meaning (GCS 2.0, the controller manuals' error table), so
//! a host that knows PI's codes understands them; 9001–9016 are the compensator's own, above
//! PI's range. The firmware's proxy raises exactly these, and the host's messages (`nanocal
//! campaign`, `nanocal device status`) come from the same table.
//!
//! | code | meaning |
//! |---:|---|
//! | 1 | parameter syntax (unparsable number, missing value) |
//! | 7 | the corrected command is outside the stage travel (PI: position out of limits) |
//! | 15 | a query names an axis that is not one of the controller's (PI: invalid axis identifier; the controller would leave it unanswered) |
//! | 22 | an axis named twice in one line (PI: axis identifier specified more than once) |
//! | 9001 | target outside the model's training envelope |
//! | 9002 | a sensor or input the model needs has failed, or the fold is stale |
//! | 9003 | no model in service (none loaded, or sensors warming up) |
//! | 9004 | a target the move needs is unknown and the controller did not tell it |
//! | 9005 | a line longer than the proxy's buffer that would have to be rewritten |
//! | 9006 | more queries in flight than the proxy can pair with replies |
//! | 9007 | the controller's position unit is not µm, or it did not tell it |
//! | 9008 | refused while compensating |
//! | 9009 | the controller speaks GCS 3.0 |
//! | 9010 | bytes from the controller were lost: the replies that were due are dropped |
//! | 9011 | a byte outside GCS's printable set in the line (a control character other than the terminating LF and a CR before it, or a byte above 7Eh) |
//! | 9012 | the corrected command is outside the controller's travel (`TMN?`/`TMX?`) by more than the clamp tolerance |
//! | 9013 | a model axis is not one of the controller's axes (`SAI?`) |
//! | 9014 | the controller does not answer (identification unanswered or unusable, or silent while the line waited) |
//! | 9015 | the controller's identification (`*IDN?`) names another stage serial than the model was fitted on, and the setting `allow_other_stage` is off |
//! | 9016 | a move the proxy would have to split into two commands, one of which the controller might refuse while it accepts the other: `MVR` of a model axis and another axis in one line, or `GOH` of all axes while the controller's axes (`SAI?`) are unknown |

code_enum! {
    /// A GCS error the compensator raises (see the module's table).
    pub enum GcsErrorCode: i32 {
        /// PI's code 1: illegal parameter / syntax — an unparsable number or a missing value.
        ParamSyntax = 1 => "parameter syntax: unparsable number or missing value",
        /// PI's code 7: position out of limits — the corrected command is outside the stage
        /// travel.
        PosOutOfLimits = 7 => "position out of limits: the corrected command is outside the stage travel",
        /// PI's code 15: invalid axis identifier — a query names an axis that is not one of
        /// the controller's (`SAI?`), which the controller would leave unanswered.
        InvalidAxis = 15 => "invalid axis identifier: not one of the controller's axes",
        /// PI's code 22: axis identifier specified more than once — the controller refuses
        /// such a line as a whole, so the proxy does too (any axis, the model's or another).
        DoubleAxis = 22 => "axis identifier specified more than once in one line",
        /// The target lies outside the model's training envelope.
        OutsideEnvelope = 9001 => "target outside the model's training envelope",
        /// A sensor or input the model needs has failed, or the fold is stale (sensor task
        /// stalled): moves are refused.
        SensorFault = 9002 => "a sensor or input the model needs has failed, or the fold is stale",
        /// No model is in service (none loaded and not bypassed, or the sensors are still
        /// warming up after an upload or boot).
        NoModel = 9003 => "no model in service (none loaded, or the sensors are warming up)",
        /// A target the move needs is unknown and the controller did not tell it (`MOV?`
        /// unanswered).
        TargetUnknown = 9004 => "a target the move needs is unknown and the controller did not tell it (MOV? unanswered)",
        /// The line is longer than the proxy's buffer and would have to be rewritten.
        LineTooLong = 9005 => "line longer than the compensator's buffer that would have to be rewritten",
        /// More queries in flight than the proxy can pair with their replies.
        TooManyQueries = 9006 => "too many queries in flight (more than the compensator pairs with replies)",
        /// The controller's position unit (`PUN?`) of a model axis is not the model's µm, or
        /// the controller did not tell it: moves are refused.
        UnitMismatch = 9007 => "the controller's position unit is not the model's µm, or PUN? went unanswered",
        /// The command would move an axis to a target the model never saw, or change what the
        /// controller's positions mean: refused while compensating.
        RefusedWhileCompensating = 9008 => "refused while compensating: the command would move a calibrated axis uncorrected or redefine its positions",
        /// The controller speaks GCS 3.0 (`CSV?` above 2), which the proxy does not rewrite:
        /// moves are refused.
        Gcs3 = 9009 => "the controller speaks GCS 3.0, which the compensator does not support",
        /// Bytes from the controller were lost (a UART overrun, a full receive buffer): the
        /// replies that were due are dropped and the targets forgotten; a move that needs one
        /// asks `MOV?` afresh.
        LinkLost = 9010 => "bytes from the controller were lost: the replies that were due were dropped",
        /// The line holds a byte outside GCS's printable set (a control character other than
        /// the terminating LF and a CR before it, or a byte above 7Eh): the proxy could not
        /// classify it, so it is not forwarded.
        NotPrintable = 9011 => "the line holds a byte outside GCS's printable set (a control character or a byte above 7Eh); not forwarded",
        /// The corrected command is outside the controller's travel (`TMN?`/`TMX?`) by more
        /// than the clamp tolerance (0.1 µm): the controller would refuse it.
        OutsideControllerTravel = 9012 => "the corrected command is outside the controller's travel (TMN?/TMX?) by more than the 0.1 µm clamp tolerance",
        /// A model axis is not one of the controller's axes (`SAI?`): moves are refused.
        NotAnAxis = 9013 => "a model axis is not one of the controller's axes (SAI?)",
        /// The controller does not answer (its identification `*IDN?` went unanswered or is no
        /// usable marker, or it went silent while the line waited for it): not forwarded.
        NoAnswer = 9014 => "the controller does not answer (identification unanswered or unusable, or silent while the line waited)",
        /// The controller's identification (`*IDN?`) names another stage serial than the
        /// model's blob was fitted on (or none): moves are refused unless the setting
        /// `allow_other_stage` is on (`nanocal_model::provenance`).
        StageMismatch = 9015 => "the controller is another stage than the model was fitted on (its *IDN? serial differs); set allow_other_stage to compensate it anyway",
        /// A move the proxy would have to split into two commands, of which the controller
        /// might refuse one and execute the other (the host's line would have moved nothing):
        /// a relative move (`MVR`) naming a model axis and another axis — the other axes'
        /// relative part cannot join the model axes' corrected absolute `MOV` — or `GOH` of all
        /// axes while the controller's axes (`SAI?`) are unknown. Send the other axes on a
        /// line of their own.
        SplitMove = 9016 => "a move that names a model axis and another axis in a form the compensator would have to split into two commands (MVR, or GOH of all axes with the controller's axes unknown); send the other axes on a line of their own",
    }
}

impl GcsErrorCode {
    /// True for the compensator's own codes (9001 and up), false for PI's.
    pub const fn is_compensators(self) -> bool {
        self.code() >= 9000
    }
}
