//! What a snapshot keeps of the FC (docs/snapshots.md): the truth it flies (orbit, attitude,
//! sensors, wheels), its non-volatile state (the onboard TLE, the RTC, its clock's errors),
//! its flight software (ADCS, target, scripts, SAFE, the store, time sync, periodic
//! telemetry) and counts. Of its configuration, the parts the FC's parameters write (the
//! ADCS's and sensors', SAFE's, the store's, time sync's); the rest is the scenario's. The
//! boards are the run's.

use snap::{Reader, Snap, SnapError, SnapNew, Writer};

use crate::{EnvModel, FcApp, FcEvent, Fsw, OnboardOrbit, Target, TimedFcEvent, WheelFault};

snap::unit_enum!(WheelFault { Stuck, Off });
snap::fields!(TimedFcEvent { at, event });
snap::fields!(Target {
    mode,
    attitude,
    attitude_set,
    point,
    point_set
});
snap::fields!(Fsw {
    adcs,
    target,
    scripts,
    output,
    request_mode,
    gps_fix;
    in_place
});

impl Snap for FcEvent {
    fn save(&self, w: &mut Writer) {
        match self {
            FcEvent::Script(text) => (0u8, text.clone()).save(w),
            FcEvent::Sensor(id, fault) => (1u8, *id, *fault).save(w),
            FcEvent::Wheel(i, fault) => (2u8, *i, *fault).save(w),
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        *self = SnapNew::read(r)?;
        Ok(())
    }
}

impl SnapNew for FcEvent {
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let at = r.at();
        Ok(match u8::read(r)? {
            0 => FcEvent::Script(SnapNew::read(r)?),
            1 => FcEvent::Sensor(SnapNew::read(r)?, SnapNew::read(r)?),
            2 => FcEvent::Wheel(SnapNew::read(r)?, SnapNew::read(r)?),
            _ => {
                return Err(SnapError::Bad {
                    what: "FcEvent",
                    at,
                });
            }
        })
    }
}

/// A model that may have failed to build (no TLE, one SGP4 refuses): its state when built,
/// nothing when not (a rebuild from the same lines fails the same way).
fn save_model(m: &Result<EnvModel, crate::OrbitError>, w: &mut Writer) {
    match m {
        Ok(m) => {
            true.save(w);
            m.save(w);
        }
        Err(_) => false.save(w),
    }
}

fn load_model(
    m: &mut Result<EnvModel, crate::OrbitError>,
    r: &mut Reader<'_>,
) -> Result<(), SnapError> {
    let at = r.at();
    match (bool::read(r)?, m) {
        (true, Ok(m)) => m.load(r),
        (false, Err(_)) => Ok(()),
        _ => Err(SnapError::Bad {
            what: "an FC orbit model (built otherwise)",
            at,
        }),
    }
}

/// The onboard TLE: its lines; the model is rebuilt from them, then its caches loaded.
fn save_onboard(o: &Option<OnboardOrbit>, w: &mut Writer) {
    match o {
        None => false.save(w),
        Some(OnboardOrbit {
            lines,
            model,
            same_as_truth,
        }) => {
            true.save(w);
            lines.save(w);
            same_as_truth.save(w);
            save_model(model, w);
        }
    }
}

fn load_onboard(o: &mut Option<OnboardOrbit>, r: &mut Reader<'_>) -> Result<(), SnapError> {
    if !bool::read(r)? {
        *o = None;
        return Ok(());
    }
    let lines: icd::fc::TleLines = SnapNew::read(r)?;
    let same_as_truth = bool::read(r)?;
    let (l1, l2) = lines.text();
    let mut model = crate::truth_model(Some(&(l1, l2)));
    load_model(&mut model, r)?;
    *o = Some(OnboardOrbit {
        lines,
        model,
        same_as_truth,
    });
    Ok(())
}

impl Snap for FcApp {
    fn save(&self, w: &mut Writer) {
        let FcApp {
            cfg,
            dt_ns: _,
            publish_every: _,
            truth_orbit,
            att,
            sensors,
            wheel_fault,
            mtq_applied_am2,
            wheel_cmd_nm,
            next_tick,
            ticks,
            timeline,
            env,
            readings,
            onboard,
            gps_models,
            rtc_offset_ns,
            clock,
            power_on,
            reset_cause,
            power_was_lost,
            fsw,
            refused,
            denied,
            periodic,
            periodic_next,
            time_sync,
            safe,
            store,
            store_now,
            log,
            out,
            truth_board: _,
            truth_refused_in_a_row,
            burns: _,
            burns_applied_until_ns,
        } = self;
        for part in [
            &cfg.adcs as &dyn Snap,
            &cfg.sensors,
            &cfg.safe,
            &cfg.store,
            &cfg.time_sync,
        ] {
            part.save(w);
        }
        save_model(truth_orbit, w);
        for part in [
            att as &dyn Snap,
            sensors,
            wheel_fault,
            mtq_applied_am2,
            wheel_cmd_nm,
            next_tick,
            ticks,
            timeline,
            env,
            readings,
        ] {
            part.save(w);
        }
        save_onboard(onboard, w);
        for part in [
            gps_models as &dyn Snap,
            rtc_offset_ns,
            clock,
            power_on,
            reset_cause,
            power_was_lost,
            fsw,
            refused,
            denied,
            periodic,
            periodic_next,
            time_sync,
            safe,
            store,
            store_now,
            log,
            out,
            truth_refused_in_a_row,
            burns_applied_until_ns,
        ] {
            part.save(w);
        }
    }

    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        let FcApp {
            cfg,
            dt_ns: _,
            publish_every: _,
            truth_orbit,
            att,
            sensors,
            wheel_fault,
            mtq_applied_am2,
            wheel_cmd_nm,
            next_tick,
            ticks,
            timeline,
            env,
            readings,
            onboard,
            gps_models,
            rtc_offset_ns,
            clock,
            power_on,
            reset_cause,
            power_was_lost,
            fsw,
            refused,
            denied,
            periodic,
            periodic_next,
            time_sync,
            safe,
            store,
            store_now,
            log,
            out,
            truth_board: _,
            truth_refused_in_a_row,
            burns: _,
            burns_applied_until_ns,
        } = self;
        for part in [
            &mut cfg.adcs as &mut dyn Snap,
            &mut cfg.sensors,
            &mut cfg.safe,
            &mut cfg.store,
            &mut cfg.time_sync,
        ] {
            part.load(r)?;
        }
        load_model(truth_orbit, r)?;
        for part in [
            att as &mut dyn Snap,
            sensors,
            wheel_fault,
            mtq_applied_am2,
            wheel_cmd_nm,
            next_tick,
            ticks,
            timeline,
            env,
            readings,
        ] {
            part.load(r)?;
        }
        load_onboard(onboard, r)?;
        for part in [
            gps_models as &mut dyn Snap,
            rtc_offset_ns,
            clock,
            power_on,
            reset_cause,
            power_was_lost,
            fsw,
            refused,
            denied,
            periodic,
            periodic_next,
            time_sync,
            safe,
            store,
            store_now,
            log,
            out,
            truth_refused_in_a_row,
            burns_applied_until_ns,
        ] {
            part.load(r)?;
        }
        Ok(())
    }
}
