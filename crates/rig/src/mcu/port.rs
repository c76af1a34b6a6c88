//! Finding and opening the rig's serial port.
//!
//! The port is found by what it is, not by where the kernel put it: USB
//! vendor id, product id and serial number (the `/dev/ttyACM` number can
//! change on every plug), or a fixed path such as the udev rule's
//! `/dev/reflectometer/mcu` symlink (which the simulator also provides).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tokio_serial::{SerialPortBuilderExt, SerialStream};

use super::client::LinkError;

/// Default line rate. USB CDC ignores it; a real UART bridge uses it.
pub const DEFAULT_BAUD: u32 = 1_000_000;

/// Where to find the MCU.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "by")]
pub enum PortLocator {
    /// A device path (or a symlink to one).
    Path { path: PathBuf },
    /// A USB serial device with these ids (hex in the rig file).
    Usb { vid: u16, pid: u16, serial: Option<String> },
}

impl PortLocator {
    /// The device path to open now.
    pub fn resolve(&self) -> Result<PathBuf, LinkError> {
        match self {
            PortLocator::Path { path } => {
                if path.exists() {
                    Ok(path.clone())
                } else {
                    Err(LinkError::Io(std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        format!(
                            "{} does not exist (is the rig plugged in and the udev rule installed?)",
                            path.display()
                        ),
                    )))
                }
            }
            PortLocator::Usb { vid, pid, serial } => {
                let ports = tokio_serial::available_ports().map_err(|e| LinkError::Io(std::io::Error::other(e)))?;
                for p in ports {
                    if let tokio_serial::SerialPortType::UsbPort(u) = &p.port_type {
                        let serial_ok = serial.as_ref().is_none_or(|s| u.serial_number.as_deref() == Some(s.as_str()));
                        if u.vid == *vid && u.pid == *pid && serial_ok {
                            return Ok(PathBuf::from(p.port_name));
                        }
                    }
                }
                Err(LinkError::Io(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!(
                        "no USB serial device {vid:04x}:{pid:04x}{} is connected (check the cable; `lsusb` lists devices)",
                        serial.as_ref().map(|s| format!(" with serial {s}")).unwrap_or_default()
                    ),
                )))
            }
        }
    }

    pub fn describe(&self) -> String {
        match self {
            PortLocator::Path { path } => path.display().to_string(),
            PortLocator::Usb { vid, pid, serial } => {
                format!(
                    "USB {vid:04x}:{pid:04x}{}",
                    serial.as_ref().map(|s| format!(" serial {s}")).unwrap_or_default()
                )
            }
        }
    }
}

/// Open a serial device for the protocol: raw 8N1, exclusive, input flushed.
pub fn open_serial(path: &Path, baud: u32) -> Result<SerialStream, LinkError> {
    let port = tokio_serial::new(path.to_string_lossy(), baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| {
            LinkError::Io(std::io::Error::other(format!(
                "cannot open {}: {e} (is your user in the dialout group, and no other program using the port?)",
                path.display()
            )))
        })?;
    // Stale bytes from before we opened the port are not replies to us.
    use tokio_serial::SerialPort;
    let _ = port.clear(tokio_serial::ClearBuffer::All);
    Ok(port)
}
