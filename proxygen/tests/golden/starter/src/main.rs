//! my-machine: connects to the machine, binds every device the scan found
//! to its proxy and prints what it found. Start here.
//!
//! ```text
//! cargo run -- --sim machine.toml     # a simulated machine
//! cargo run -- --port /dev/ttyACM0    # a module or hub over USB
//! ```

mod proxies;

use osap_host::link::serial;
use osap_sim::machine::{self, SimMachine};
use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use std::error::Error;

#[tokio::main]
async fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let host = Host::start(HostConfig::default())?;
    // Keep the machine (or the serial link) alive while the script runs.
    let mut _sim: Option<SimMachine> = None;
    let mut _link = None;
    match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["--sim", file] => _sim = Some(SimMachine::start(&host, &machine::load(file)?).await?),
        ["--port", path] => _link = Some(serial::spawn_serial(&host, path, serial::DEFAULT_BAUD).await?),
        _ => return Err("usage: my-machine --sim FILE | --port PATH".into()),
    }
    let mut manager = Manager::new(&host).await?;
    manager.refresh().await?;
    println!("{} runtimes found", manager.som().runtimes.len());

    let x = proxies::Stepper::bind(&manager, "x")?;
    println!("{:?}: {} {}", x.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let y = proxies::Stepper::bind(&manager, "y")?;
    println!("{:?}: {} {}", y.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let z = proxies::Stepper::bind(&manager, "z")?;
    println!("{:?}: {} {}", z.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let tool = proxies::Stepper::bind(&manager, "tool")?;
    println!("{:?}: {} {}", tool.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);

    // Your script goes here, e.g. (on a stepper named x):
    //   let (t, p) = { let o = x.get_position().await?; (o.time, o.position) };
    Ok(())
}
