//! Networks of RS-485 buses behind hubs, of any size: the scale test's
//! shape (`osap-sim/topologies/bus32.toml` is `bus_tree(4, 8)`), for
//! measuring how scans and clock sync grow with the module count.

use super::{SimSpec, SpecError};

/// Hubs' oscillator errors, ppm, in turn.
const HUB_PPM: [f64; 4] = [-35.0, 15.0, 50.0, -60.0];

/// A drop's oscillator error, ppm: spread over ±70 ppm, whole ppm.
fn drop_ppm(i: usize) -> f64 {
    ((i * 37) % 141) as f64 - 70.0
}

/// A hub (`root`) on USB with `buses` hubs (`hub1`, ...) on its UARTs, each
/// heading a 1 Mbit/s RS-485 bus (`bus1`, ...) of `drops` steppers (`a1`,
/// `a2`, ... on the first bus, `b1`, ... on the second). The drops'
/// oscillators are spread over ±70 ppm, the hubs' over ±60.
///
/// # Errors
/// If `buses` is 0 or more than 7 (a hub's UARTs), or `drops` is 0 or
/// more than 26.
pub fn bus_tree(buses: usize, drops: usize) -> Result<SimSpec, SpecError> {
    if !(1..=7).contains(&buses) || !(1..=26).contains(&drops) {
        return Err(SpecError::Invalid {
            context: "bus tree".into(),
            message: format!("{buses} buses of {drops} drops: 1 to 7 buses of 1 to 26 drops"),
        });
    }
    let n = buses * drops;
    let mut t = format!(
        "name = \"bus{n}\"\n\n[[module]]\nname = \"root\"\ntype = \"hub\"\nrate_ppm = -20.0\n"
    );
    for h in 1..=buses {
        t += &format!(
            "\n[[module]]\nname = \"hub{h}\"\ntype = \"hub\"\nrate_ppm = {:?}\n",
            HUB_PPM[(h - 1) % HUB_PPM.len()]
        );
    }
    let letter = |h: usize| char::from(b'a' + (h - 1) as u8);
    for h in 1..=buses {
        for k in 1..=drops {
            let i = (h - 1) * drops + k - 1;
            t += &format!(
                "\n[[module]]\nname = \"{}{k}\"\ntype = \"stepper\"\nrate_ppm = {:?}\n",
                letter(h),
                drop_ppm(i)
            );
        }
    }
    t += "\n[[link]]\na = \"host\"\nb = \"root\"\nkind = \"usb\"\n";
    for h in 1..=buses {
        t +=
            &format!("\n[[link]]\na = \"root\"\nb = \"hub{h}\"\nkind = \"uart\"\nbaud = 2000000\n");
    }
    for h in 1..=buses {
        let names: Vec<String> = (1..=drops)
            .map(|k| format!("\"{}{k}\"", letter(h)))
            .collect();
        t += &format!(
            "\n[[bus]]\nname = \"bus{h}\"\nhead = \"hub{h}\"\ndrops = [{}]\nbaud = 1000000\n",
            names.join(", ")
        );
    }
    SimSpec::parse(&t)
}
