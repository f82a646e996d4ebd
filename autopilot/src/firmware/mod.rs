//! RTIC 2 application of the autopilot firmware (thumbv7em-none-eabihf only).
