//! §6 initialisation: the restore decision of device support, init_record pass 1 and the
//! boot-time reconciliation of speeds, resolution and limits.

use super::MotorRecord;
use crate::engine::commands::{DeviceStatus, MotorCommand};
use crate::engine::maths::{nint, raw_position};
use zmotor_msgs::menus::choice;
use zmotor_msgs::Field;

impl MotorRecord {
    /// §6.4 step 3–4: what device support writes before the record reads any status: the encoder
    /// ratio, and the restored dial position if RSTM says so. `controller_steps` is the motor
    /// position the controller reports at boot.
    #[must_use = "the commands are to be delivered to the device"]
    pub fn restore_commands(&self, controller_steps: f64) -> Vec<MotorCommand> {
        let f = &self.f;
        let mut cmds = vec![if f.eres == 0.0 {
            MotorCommand::SetEncRatio(1.0, 1.0)
        } else {
            MotorCommand::SetEncRatio(f.mres, f.eres)
        }];
        let rdbd_eff = f.rdbd.abs().max(f.mres.abs());
        let use_rel = f.rtry != 0 && f.rmod != choice::RMOD_IN_POSITION && (f.ueip != 0 || f.urip != 0);
        let near_zero = f.dval.abs() > rdbd_eff && f.mres != 0.0 && (controller_steps * f.mres).abs() < rdbd_eff;
        let load = match f.rstm {
            1 => true,
            2 => near_zero,
            3 => near_zero || use_rel,
            _ => false,
        };
        // A position the driver cannot hold is not restored (Z20).
        if load && raw_position(f.dval / f.mres).is_some() {
            cmds.push(MotorCommand::LoadPos(f.dval / f.mres));
        }
        cmds
    }

    /// §6.2 steps 6–14, with the first status read from the device.
    pub fn init(&mut self, status: DeviceStatus) {
        // UDF is cleared when DOL is a constant link (none, or a number: the normal case); a
        // DOL that is a key leaves it until its first good read (§6.2 step 6).
        if self.f.dol.is_empty() || self.f.dol.trim().parse::<f64>().is_ok() {
            self.f.udf = 0;
        }
        self.pending_status = Some(status);
        self.update_values();
        if self.f.eres == 0.0 {
            self.f.eres = self.f.mres;
        }
        self.process_motor_info(true);
        if self.f.omsl != choice::OMSL_CLOSED_LOOP {
            self.f.val = self.f.rbv;
            self.f.dval = self.f.drbv;
            self.f.rval = nint(self.f.dval / self.f.mres);
        }
        self.set_dial_limit(true);
        self.set_dial_limit(false);
        let f = &mut self.f;
        f.dmov = 1;
        f.movn = 0;
        f.spmg = choice::SPMG_GO;
        f.lspg = choice::SPMG_GO;
        f.diff = f.dval - f.drbv;
        f.rdif = nint(f.diff / f.mres);
        f.lval = f.val;
        f.ldvl = f.dval;
        f.lrvl = f.rval;
        self.f.lvio = i16::from(self.readback_violates_limits());
        self.mark(Field::MSTA);
        for field in [Field::VAL, Field::DVAL, Field::RVAL, Field::DMOV, Field::LVIO, Field::DIFF, Field::RDIF] {
            self.mark(field);
        }
        let alarm = self.alarm();
        self.monitor(alarm);
    }

    /// §6.3
    pub(super) fn check_speed_and_resolution(&mut self) {
        let f = &mut self.f;
        if f.srev <= 0 {
            f.srev = 200;
        }
        if f.urev != 0.0 {
            f.mres = f.urev / f64::from(f.srev);
        }
        if f.mres == 0.0 {
            f.mres = 1.0;
        }
        if f.urev != f.mres * f64::from(f.srev) {
            f.urev = f.mres * f64::from(f.srev);
        }
        let u = f.urev.abs();
        if f.smax > 0.0 {
            f.vmax = f.smax * u;
        } else if f.vmax > 0.0 {
            f.smax = f.vmax / u;
        } else {
            f.smax = 0.0;
            f.vmax = 0.0;
        }
        if f.sbas != 0.0 {
            self.range_check(Field::SBAS, 0.0, self.f.smax);
            self.f.vbas = self.f.sbas * u;
        } else {
            self.range_check(Field::VBAS, 0.0, self.f.vmax);
            self.f.sbas = self.f.vbas / u;
        }
        if self.f.s != 0.0 {
            self.range_check(Field::S, self.f.sbas, self.f.smax);
            self.f.velo = self.f.s * u;
        } else {
            self.range_check(Field::VELO, self.f.vbas, self.f.vmax);
            self.f.s = self.f.velo / u;
        }
        // Raw limits win at boot. Departure Z3: with MRES < 0 the raw low limit is the dial high
        // limit with its sign (the reference drops the sign, Q3).
        let f = &mut self.f;
        let (raw_for_high, raw_for_low) = if f.mres > 0.0 { (f.rhlm, f.rllm) } else { (f.rllm, f.rhlm) };
        if raw_for_high != 0.0 {
            f.dhlm = raw_for_high * f.mres;
        }
        if raw_for_low != 0.0 {
            f.dllm = raw_for_low * f.mres;
        }
        (f.rhlm, f.rllm) =
            if f.mres > 0.0 { (f.dhlm / f.mres, f.dllm / f.mres) } else { (f.dllm / f.mres, f.dhlm / f.mres) };
        if self.f.sbak != 0.0 {
            self.range_check(Field::SBAK, self.f.sbas, self.f.smax);
            self.f.bvel = self.f.sbak * u;
        } else {
            self.range_check(Field::BVEL, self.f.vbas, self.f.vmax);
            self.f.sbak = self.f.bvel / u;
        }
        if self.f.accs > 0.0 {
            self.accl_from_accs();
        } else {
            if self.f.accl == 0.0 {
                self.f.accl = 0.1;
            }
            self.accs_from_accl();
        }
        let f = &mut self.f;
        if f.bacc == 0.0 {
            f.bacc = 0.1;
        }
        if f.jvel == 0.0 {
            f.jvel = f.velo;
        } else {
            self.range_check(Field::JVEL, self.f.vbas, self.f.vmax);
        }
        let f = &mut self.f;
        if f.jar == 0.0 {
            f.jar = f.velo / f.accl;
        }
        if f.hvel == 0.0 {
            f.hvel = f.vbas;
        } else {
            self.range_check(Field::HVEL, self.f.vbas, self.f.vmax);
        }
    }
}
