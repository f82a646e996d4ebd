//! RTIC 2 application of the stereo-board firmware (thumbv7em-none-eabihf only).
