//! CubeMars AK-series actuators in MIT mode: the [`MitMotor`] driver with the model's command
//! ranges enforced by the device itself.
//!
//! MIT-mode ranges per model, from the CubeMars *AK Series Actuator Driver Manual* V1.0.8,
//! p. 50 (<https://www.manualshelf.com/manual/cubemars/ak80-64-kv80/ak80-64-ak-series-actuator-driver-manual-v1-0-8-english-somali/page-50.html>;
//! also `/work/shared/reference/protocols.md` §2.1):
//!
//! | model | position (rad) | velocity (rad/s) | torque (N·m) | kp | kd |
//! |---|---|---|---|---|---|
//! | AK60-6 | ±12.5 | ±45 | ±15 | 0–500 | 0–5 |
//! | AK70-10 | ±12.5 | ±50 | ±25 | 0–500 | 0–5 |
//! | AK80-9 | ±12.5 | ±50 | ±18 | 0–500 | 0–5 |
//!
//! The values are those of [`Model::limits`] (the codec's table, which the `can_motors` stage
//! and the simulator quantise with); a test here checks them against the manual's numbers.
//! Firmware with other ranges (the V1.1/V2 variants in `mit_can::variants`) is not one of
//! these models.
//!
//! The stage quantises a command with the ranges it is configured with for the motor's ID
//! (its `model` or `models` parameter), so that configuration must name the same model: the
//! device clamps every setpoint into its own model's ranges (counted, [`AkMotor::clamped`])
//! whatever the stage does, and a non-finite setpoint is ignored, as [`MitMotor`] does.

use conductor_protocols::mit_can::{Limits, Model, Range};

use crate::component::{Channel, Device, SafeAction, TickCtx};
use crate::device::{mit_channel, MitMotor};
use crate::kinds::{Build, Choice, Disagreement, KindSpec, ParamSpec, Params};
use crate::lifecycle::{DeviceStatus, Startup};
use crate::message::{Credential, Reply, Request, Update};
use crate::queue::Bounded;

/// The AK models this kind accepts (manifest parameter `model`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AkModel {
    /// AK60-6.
    Ak60_6,
    /// AK70-10.
    Ak70_10,
    /// AK80-9.
    Ak80_9,
}

crate::choices!(AkModel {
    Ak60_6 = "ak60-6",
    Ak70_10 = "ak70-10",
    Ak80_9 = "ak80-9",
});

impl AkModel {
    /// The codec's model.
    pub const fn model(self) -> Model {
        match self {
            AkModel::Ak60_6 => Model::Ak60_6,
            AkModel::Ak70_10 => Model::Ak70_10,
            AkModel::Ak80_9 => Model::Ak80_9,
        }
    }

    /// Its MIT-mode ranges (the table above).
    pub const fn limits(self) -> Limits {
        self.model().limits()
    }
}

/// An AK-series motor: an [`MitMotor`] whose setpoints are clamped into its model's ranges.
#[derive(Debug)]
pub struct AkMotor {
    motor: MitMotor,
    model: AkModel,
    clamped: u64,
}

impl AkMotor {
    /// Motor `model` with CAN ID `cred.id`, gains `kp`/`kd` until written.
    pub fn new(model: AkModel, cred: Credential, kp: f32, kd: f32) -> Self {
        Self {
            motor: MitMotor::new(cred, kp, kd),
            model,
            clamped: 0,
        }
    }

    /// Setpoints clamped into the model's ranges since start.
    pub fn clamped(&self) -> u64 {
        self.clamped
    }

    /// The range of command channel `channel`, if it is one.
    fn range(&self, channel: usize) -> Option<Range> {
        let l = self.model.limits();
        match channel {
            mit_channel::POSITION => Some(l.p),
            mit_channel::VELOCITY => Some(l.v),
            mit_channel::TORQUE => Some(l.t),
            mit_channel::KP => Some(l.kp),
            mit_channel::KD => Some(l.kd),
            _ => None,
        }
    }
}

impl Device for AkMotor {
    fn credential(&self) -> Credential {
        self.motor.credential()
    }
    fn channels(&self) -> &[Channel] {
        self.motor.channels()
    }
    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.motor.sample(channel, ctx, out);
    }
    fn write(&mut self, channel: usize, value: f64, ctx: TickCtx) {
        let value = match self.range(channel) {
            Some(r) if value.is_finite() => {
                let v = value.clamp(f64::from(r.min), f64::from(r.max));
                if v != value {
                    self.clamped += 1;
                }
                v
            }
            _ => value,
        };
        self.motor.write(channel, value, ctx);
    }
    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.motor.flush(ctx, out);
    }
    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>) {
        self.motor.reply(reply, out);
    }
    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.motor.safe(action, ctx, out);
    }
    fn status(&self) -> DeviceStatus {
        self.motor.status()
    }
    fn bring_up(&mut self, startup: Startup, ctx: TickCtx) {
        self.motor.bring_up(startup, ctx);
    }
    fn bus_lost(&mut self) {
        self.motor.bus_lost();
    }
    fn accepts(&self, channel: usize) -> bool {
        self.motor.accepts(channel)
    }
    fn trip(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>) {
        self.motor.trip(action, ctx, out);
    }
    fn report(&mut self, ctx: TickCtx, out: &mut Bounded<Update>) {
        self.motor.report(ctx, out);
    }
    fn describe(&self) -> String {
        format!(
            "CubeMars {} (MIT mode, {} setpoints clamped); {}",
            self.model.name().to_uppercase(),
            self.clamped,
            self.motor.describe()
        )
    }
}

/// The `cubemars_ak` device kind.
pub const KIND: KindSpec = KindSpec {
    kind: "cubemars_ak",
    params: &[
        ParamSpec::choice::<AkModel>("model", "ak80-9", "the AK model: its MIT-mode ranges (CubeMars manual V1.0.8 p. 50) bound every setpoint; the can_motors stage must be configured with the same model for this ID"),
        ParamSpec::float("kp", 0.0, Some((0.0, 500.0)), "position gain until the kp channel is written"),
        ParamSpec::float("kd", 0.0, Some((0.0, 5.0)), "velocity gain until the kd channel is written"),
    ],
    doc: "A CubeMars AK-series actuator in MIT mode (AK60-6: ±12.5 rad, ±45 rad/s, ±15 N·m; \
          AK70-10: ±12.5, ±50, ±25; AK80-9: ±12.5, ±50, ±18; kp 0–500, kd 0–5): an `mit_motor` \
          whose position, velocity, torque, kp and kd setpoints are clamped into its model's \
          ranges. Channels, bring-up and safe actions as `mit_motor`.",
    build: Build::Device {
        protocols: &["can_motors"],
        safe_actions: &["torque_off", "damp", "hold", "setpoint"],
        build: |p, cred| {
            Ok(Box::new(AkMotor::new(
                p.choice("model")?,
                cred,
                p.float("kp")? as f32,
                p.float("kd")? as f32,
            )))
        },
        agrees: Some(agrees_with_stage),
    },
};

/// The stage encodes this motor's frames with its own model table, so it must hold this
/// model's ranges for this id: otherwise a torque clamped to the device's model goes out
/// scaled by another's (20 N·m on an AK70-10 behind an AK80-9 stage is sent as 25 N·m).
fn agrees_with_stage(device: &Params, stage: &Params, id: u32) -> Result<(), Disagreement> {
    // Parameters that do not parse are reported by the validator on their own.
    let (Ok(model), Ok(at_stage)) = (
        device.choice::<AkModel>("model"),
        crate::protocol_stage::can_motors::stage_limits(stage, id),
    ) else {
        return Ok(());
    };
    let l = model.limits();
    if l == at_stage {
        return Ok(());
    }
    let ranges = |l: &Limits| format!("±{} rad, ±{} rad/s, ±{} N·m", l.p.max, l.v.max, l.t.max);
    Err(Disagreement {
        param: "model",
        expected: format!(
            "the same ranges as its can_motors stage, which encodes motor {id} with {} while {} \
             has {}: set the stage's model (or its `models` entry \"{id}={}\") to this model",
            ranges(&at_stage),
            model.name(),
            ranges(&l),
            model.name(),
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The manual's p. 50 numbers (P, V, T; kp 0–500 and kd 0–5 for all).
    #[test]
    fn ranges_are_the_manuals() {
        for (m, p, v, t) in [
            (AkModel::Ak60_6, 12.5, 45.0, 15.0),
            (AkModel::Ak70_10, 12.5, 50.0, 25.0),
            (AkModel::Ak80_9, 12.5, 50.0, 18.0),
        ] {
            let l = m.limits();
            let sym = |r: Range, x: f32| r.min == -x && r.max == x;
            assert!(sym(l.p, p) && sym(l.v, v) && sym(l.t, t), "{m}: {l:?}");
            assert_eq!(
                (l.kp.min, l.kp.max, l.kd.min, l.kd.max),
                (0.0, 500.0, 0.0, 5.0)
            );
        }
    }

    #[test]
    fn setpoints_beyond_the_model_are_clamped_and_counted() {
        let mut m = AkMotor::new(AkModel::Ak60_6, Credential::id(1), 10.0, 1.0);
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        m.write(mit_channel::TORQUE, 40.0, ctx);
        m.write(mit_channel::VELOCITY, -10.0, ctx);
        m.write(mit_channel::KD, f64::NAN, ctx);
        assert_eq!(m.clamped(), 1);
        let mut out = Bounded::with_capacity(4);
        m.flush(ctx, &mut out);
        match out.as_slice() {
            [Request {
                op: crate::message::Op::Mit { v, t, kd, .. },
                ..
            }] => assert_eq!((*v, *t, *kd), (-10.0, 15.0, 1.0)),
            other => panic!("{other:?}"),
        }
    }
}
