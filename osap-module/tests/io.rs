//! The I/O logic over a board made of memory.

use osap_core::time::{Instant, SystemInstant};
use osap_module::board::IoHw;
use osap_module::io::{Io, IoError, MAX_PULSE_US, SCHEDULED_PULSES};

#[derive(Default)]
struct Pins {
    levels: [bool; 8],
    pwm: [u16; 2],
    writes: Vec<(u8, bool)>,
}

impl IoHw for Pins {
    fn digital_pins(&self) -> u8 {
        8
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        self.levels[usize::from(pin)] = level;
        self.writes.push((pin, level));
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        self.levels[usize::from(pin)]
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        self.pwm[usize::from(channel)] = duty;
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.pwm[usize::from(channel)]
    }
    fn analog_inputs(&self) -> u8 {
        1
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        0x8000
    }
}

#[test]
fn pins_pwm_and_analog_check_their_ranges() {
    let (mut io, mut hw) = (Io::new(), Pins::default());
    assert_eq!(io.digital_write(&mut hw, 3, true), Ok(()));
    assert_eq!(io.digital_read(&mut hw, 3), Ok(true));
    assert_eq!(io.digital_write(&mut hw, 8, true), Err(IoError::NoSuchPin));
    assert_eq!(io.digital_read(&mut hw, 200), Err(IoError::NoSuchPin));
    assert_eq!(io.pwm_write(&mut hw, 1, 0.25), Ok(()));
    assert_eq!(hw.pwm[1], 16_384);
    assert_eq!(io.pwm_write(&mut hw, 0, 1.0), Ok(()));
    assert_eq!(hw.pwm[0], 65_535);
    assert_eq!(io.pwm_write(&mut hw, 0, f32::NAN), Err(IoError::BadValue));
    assert_eq!(io.pwm_write(&mut hw, 0, 1.01), Err(IoError::BadValue));
    assert_eq!(io.pwm_write(&mut hw, 2, 0.5), Err(IoError::NoSuchPin));
    let v = io.analog_read(&mut hw, 0).unwrap();
    assert!((v - 0.5).abs() < 1e-4);
    assert_eq!(io.analog_read(&mut hw, 1), Err(IoError::NoSuchPin));
}

#[test]
fn a_pulse_ends_on_time_and_restarts() {
    let (mut io, mut hw) = (Io::new(), Pins::default());
    assert_eq!(
        io.pulse(&mut hw, Instant::from_micros(1_000), 2, 500),
        Ok(())
    );
    assert!(hw.levels[2]);
    assert_eq!(
        io.wake_at(Instant::from_micros(1_000), SystemInstant::ZERO),
        Some(Instant::from_micros(1_500))
    );
    io.poll(&mut hw, Instant::from_micros(1_499), SystemInstant::ZERO);
    assert!(hw.levels[2], "still high a µs before its end");
    io.poll(&mut hw, Instant::from_micros(1_500), SystemInstant::ZERO);
    assert!(!hw.levels[2]);
    assert_eq!(
        io.wake_at(Instant::from_micros(1_500), SystemInstant::ZERO),
        None
    );
    // A write ends a running pulse; the pin then stays as written.
    io.pulse(&mut hw, Instant::from_micros(2_000), 4, 100)
        .unwrap();
    io.digital_write(&mut hw, 4, true).unwrap();
    io.poll(&mut hw, Instant::from_micros(3_000), SystemInstant::ZERO);
    assert!(hw.levels[4]);
    assert_eq!(
        io.pulse(&mut hw, Instant::ZERO, 4, MAX_PULSE_US + 1),
        Err(IoError::BadValue)
    );
    assert_eq!(
        io.pulse(&mut hw, Instant::ZERO, 9, 10),
        Err(IoError::NoSuchPin)
    );
    assert_eq!(io.pulses(), 2);
}

#[test]
fn scheduled_pulses_start_at_their_synchronized_time() {
    let (mut io, mut hw) = (Io::new(), Pins::default());
    // Local and system clocks differ by 1 000 000 µs.
    let (local, system) = (5_000u64, 1_005_000u64);
    io.pulse_at(
        &hw,
        SystemInstant::from_micros(system),
        SystemInstant::from_micros(1_006_000),
        1,
        300,
    )
    .unwrap();
    assert_eq!(
        io.wake_at(
            Instant::from_micros(local),
            SystemInstant::from_micros(system)
        ),
        Some(Instant::from_micros(6_000))
    );
    io.poll(
        &mut hw,
        Instant::from_micros(5_999),
        SystemInstant::from_micros(1_005_999),
    );
    assert!(!hw.levels[1]);
    // The loop woke 20 µs late: the pulse still ends where scheduled.
    io.poll(
        &mut hw,
        Instant::from_micros(6_020),
        SystemInstant::from_micros(1_006_020),
    );
    assert!(hw.levels[1]);
    assert_eq!(
        io.wake_at(
            Instant::from_micros(6_020),
            SystemInstant::from_micros(1_006_020)
        ),
        Some(Instant::from_micros(6_300))
    );
    io.poll(
        &mut hw,
        Instant::from_micros(6_300),
        SystemInstant::from_micros(1_006_300),
    );
    assert!(!hw.levels[1]);
    // A schedule too far ahead, and a full schedule, are refused.
    assert_eq!(
        io.pulse_at(
            &hw,
            SystemInstant::from_micros(system),
            SystemInstant::from_micros(system + 61_000_000),
            1,
            10
        ),
        Err(IoError::BadValue)
    );
    for k in 0..SCHEDULED_PULSES as u64 {
        io.pulse_at(
            &hw,
            SystemInstant::from_micros(system),
            SystemInstant::from_micros(system + 10_000 + k),
            1,
            10,
        )
        .unwrap();
    }
    assert_eq!(
        io.pulse_at(
            &hw,
            SystemInstant::from_micros(system),
            SystemInstant::from_micros(system + 20_000),
            1,
            10
        ),
        Err(IoError::Full)
    );
}
