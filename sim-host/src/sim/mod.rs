//! The closed-loop simulator of the pocket drone.
//!
//! * [`math`]: vectors and quaternions.
//! * [`dynamics`]: 6-DOF rigid body, motors, RK4, floor contact; the 40 g drone's parameters.
//! * [`imu`]: MPU-6000-class IMU at 512 Hz.
//! * [`scene`]: rooms, obstacles, procedural textures, ray intersection, clearance.
//! * [`camera`]: the stereo camera renderer (interleaved 128x96 frames).
//! * [`uart`]: the simulated UART with fault injection.
//! * [`sched`]: the virtual-clock scheduler over the boards' task tables.

pub mod boards;
pub mod camera;
pub mod dynamics;
pub mod flight;
pub mod imu;
pub mod math;
pub mod output;
pub mod scene;
pub mod sched;
pub mod uart;
