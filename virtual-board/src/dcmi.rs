//! The digital camera interface of RM0090 rev 22 chapter 15, with the camera behind it.
//!
//! rigless has no DCMI model; this is one, written against its generated `dcmi` layout, and it
//! holds the far end of the interface as rigless's card interface holds its card: the camera
//! board's sensor pair ([`crate::tcm8230`]) behind the CPLD ([`crate::cpld`]), fed by a
//! [`FrameSource`]. The board ([`crate::boards::camera`]) says what the camera's pins and the
//! interface's pins carry by handing the model a sampler ([`Dcmi::attach`]), which the SoC calls
//! before every access and event of this slot.
//!
//! | register or section | behaviour | source | test |
//! |---|---|---|---|
//! | 15.5.3 hardware synchronisation | HSYNC and VSYNC are blanking signals of the polarity `HSPOL`/`VSPOL` give; data is taken only while both are inactive; a frame starts when VSYNC turns inactive | 15.5.3, 15.8.1 | `a_wrong_sync_polarity_captures_the_blanking` |
//! | `PCKPOL` | data are taken on the edge `PCKPOL` names; the sensor launches on the other one (its register 0x02 bit 1). On the launching edge the model takes the byte before (a hold violation made deterministic) | 15.8.1 | `the_wrong_pixel_clock_edge_shifts_every_byte` |
//! | `EDM` | 8-bit: one byte per pixel clock, four to a `DR` word, first byte lowest; 10 to 14 bits: a half-word per pixel clock (the upper data lines carry 0 here) | 15.5.2, 15.8.1 | |
//! | `CM`, `CAPTURE` | snapshot: one frame from the next frame start, then `CAPTURE` clears; continuous: every frame until `CAPTURE` is cleared, which takes effect at the frame's end | 15.5.5 | `snapshot_captures_one_frame_and_clears_capture` |
//! | `FCRC` | all frames, every other, one in four | 15.8.1 | `every_other_frame_is_captured_with_fcrc_01` |
//! | `CROP`, `CWSTRT`, `CWSIZE` | lines `VST ..= VST + VLINE` of the frame, pixel clocks `HOFFCNT ..= HOFFCNT + CAPCNT` of each; the frame is complete at the end of the window's last line | 15.5.6, 15.8.7, 15.8.8 | `the_crop_window_takes_the_pixel_clocks_and_lines_it_names` |
//! | `FRAME`, `LINE`, `VSYNC`, `OVR` in `RIS`, `IER`, `MIS`, `ICR` | set at frame captured, HSYNC turning active, VSYNC turning active, a word arriving at a full FIFO; `MIS = RIS & IER`; the interrupt (position 78) stands while `MIS` is not zero; `ICR` clears | 15.7, 15.8.3 to 15.8.6 | `flags_interrupt_and_clear_as_the_manual_says` |
//! | `ERR` | embedded synchronisation only: `ESS` is not modelled (nothing is captured with it set) | 15.8.3 | |
//! | `SR` | `HSYNC`, `VSYNC` (1 during blanking) and `FNE` | 15.8.2 | |
//! | FIFO and DMA | eight words; the DMA request stands while a word waits; a `DR` read takes the oldest; a word completing while eight wait is lost and sets `OVR` | 15.5.2 | `a_stream_that_is_not_drained_overruns` |
//! | clock | with `RCC_AHB2ENR.DCMIEN` clear the interface ignores writes, reads 0 and captures nothing (and the run is told) | 6.3.11 | `nothing_without_the_interface_clock` |
//!
//! Not modelled: JPEG mode and embedded synchronisation (`JPEG`, `ESS`, `ESCR`, `ESUR`); the
//! HCLK/PIXCLK ratio of 15.4 (checked nowhere); the capture of a partial word at a frame's end
//! (dropped). Words are packed and handed to the FIFO at pixel-clock time, in steps of at most
//! eight words: the model wakes at every eighth word of a captured line, so a DMA that keeps up
//! never overruns and one that does not overruns at most eight words late.

use std::collections::VecDeque;

use rigless::device::{Device, DeviceContext, Level, RegisterFile};
use rigless::snapshot::Store;
use rigless::soc::stm32f427::Stm32f427;
use rigless::soc::stm32f427::generated::dcmi::{Register, cr, cwsize, cwstrt, icr, ris, sr};
use rigless::time::{EventId, VirtualNanos};

use crate::clock_timer::ClockTimer;
use crate::cpld::{self, Mode};
use crate::frames::{FrameSource, StereoImage};
use crate::tcm8230::{self, SensorHandle, SensorPins, StreamSetup};

/// The request the DCMI drives toward DMA2 (channel 1 of streams 1 and 7, RM0090 table 44).
pub const DMA_REQUEST: usize = 0;

/// Words the interface's FIFO holds (RM0090 15.5.2).
pub const FIFO_WORDS: usize = 8;

/// Position of the DCMI's interrupt in its table (line 78).
const INTERRUPT: usize = 0;

/// Sampling period of the camera's pins while its reset is being timed, ns (420 periods of a
/// 21 MHz clock: a reset pulse counts once two samples 100 periods apart saw it, so a pulse
/// shorter than one sampling period may be missed and one of 100 periods needs two samples).
const CLOSE_WATCH_NS: u64 = 20_000;
/// Sampling period of the camera's pins otherwise while it does not stream, ns (each sample is
/// an emulator stop: a stream starts up to this late after the sensor is set up).
const WATCH_NS: u64 = 1_000_000;

const NANOS: u128 = 1_000_000_000;

/// What the board's pins carry for the interface and the camera, sampled by the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DcmiInputs {
    /// The sensors' clock and reset pins.
    pub sensor: SensorPins,
    /// The CPLD's mode, from its select pins.
    pub cpld: Mode,
    /// `RCC_AHB2ENR.DCMIEN`.
    pub clock_enabled: bool,
    /// HSYNC, VSYNC and PIXCLK reach the interface (their pins are in the DCMI function).
    pub sync_connected: bool,
    /// Which of D0..D7 reach the interface (bit n: the pin wired to the camera's Dn is in the
    /// DCMI function); a data line that does not reads 0.
    pub data_mask: u8,
}

impl Default for DcmiInputs {
    fn default() -> Self {
        Self {
            sensor: SensorPins::default(),
            cpld: Mode::Undefined,
            clock_enabled: false,
            sync_connected: false,
            data_mask: 0,
        }
    }
}

/// Reads [`DcmiInputs`] off the part's registers and models (the board's wiring), given the
/// timer the SoC serves as a clock generator, if any ([`crate::soc::Soc::use_as_clock`]).
pub type Sampler = fn(&Stm32f427, Option<&ClockTimer>) -> DcmiInputs;

/// The far end of the interface: the sensor pair, the CPLD and what they see.
#[derive(Debug)]
pub struct Camera {
    sensor: SensorHandle,
    source: Box<dyn FrameSource>,
    scene: Option<StereoImage>,
    /// Camera frames put on the bus since the sensors first streamed.
    frames_streamed: u64,
    /// Fault: the camera has stopped (no clock out, no sync, no data).
    stopped: bool,
}

impl Camera {
    /// A camera whose sensors are `sensor` (attach its SCCB port to the board's I2C) and which
    /// sees what `source` gives.
    #[must_use]
    pub fn new(sensor: SensorHandle, source: Box<dyn FrameSource>) -> Self {
        Self {
            sensor,
            source,
            scene: None,
            frames_streamed: 0,
            stopped: false,
        }
    }

    /// The sensor pair.
    #[must_use]
    pub fn sensor(&self) -> &SensorHandle {
        &self.sensor
    }
}

/// Counts of what happened on the interface since the bench began.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DcmiStats {
    /// Camera frames the sensors put on the bus.
    pub frames_streamed: u64,
    /// Frames the interface captured whole (`FRAME` events).
    pub frames_captured: u64,
    /// Words handed to the FIFO.
    pub words: u64,
    /// Words lost to an overrun.
    pub words_lost: u64,
    /// `DR` reads (by the DMA or the CPU).
    pub reads: u64,
}

/// One line of a frame as the interface sees it: an interval with HSYNC inactive.
#[derive(Debug, Clone)]
struct Line {
    /// First pixel clock, counted from the camera frame's start.
    start: u64,
    /// The bytes taken, one per pixel clock (already through the sampling edge and data lines).
    bytes: Vec<u8>,
}

/// A camera frame on the bus, as the interface sees it.
#[derive(Debug, Clone)]
struct Stream {
    /// The camera frame's number (0 for the first the sensors streamed).
    index: u64,
    hz: u64,
    /// The camera frame's start (its VBLK turning inactive).
    origin: VirtualNanos,
    /// Pixel clocks of the camera frame.
    period: u64,
    /// The interface's frame: VSYNC inactive from `frame_start` to `frame_end` (pixel clocks).
    frame_start: u64,
    frame_end: u64,
    lines: Vec<Line>,
    phase: Phase,
    /// The line being taken and the next byte of it.
    line: usize,
    byte: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Before,
    Within,
    After,
}

impl Stream {
    /// The instant pixel clock `clocks` of the frame ends (rounded up to the nanosecond).
    fn at(&self, clocks: u64) -> VirtualNanos {
        VirtualNanos(
            self.origin.0 + (u128::from(clocks) * NANOS).div_ceil(u128::from(self.hz)) as u64,
        )
    }

    /// Pixel clocks completed by `now`.
    fn clocks_by(&self, now: VirtualNanos) -> u64 {
        (u128::from(now.0.saturating_sub(self.origin.0)) * u128::from(self.hz) / NANOS) as u64
    }
}

/// Capture of the current interface frame.
#[derive(Debug, Clone, Copy, Default)]
struct Capture {
    /// This frame is being captured.
    active: bool,
    /// Lines seen in this frame.
    line: u32,
    /// Frames started while `CAPTURE` stood, for `FCRC`.
    counted: u64,
}

/// The DCMI model, and the camera on its far end.
#[derive(Debug, Default)]
pub struct Dcmi {
    camera: Option<Camera>,
    sampler: Option<Sampler>,
    inputs: DcmiInputs,
    stream: Option<Stream>,
    fifo: VecDeque<u32>,
    packing: (u32, u32),
    capture: Capture,
    request: Level,
    interrupt: Level,
    event: Option<(EventId, VirtualNanos)>,
    told_clock: bool,
    /// The registers as of the last write the interface took (with its clock on).
    shadow: [u64; Register::ALL.len()],
    /// Each frame captured whole: the camera frame's number and the instant of `FRAME`.
    captured: Vec<(u64, VirtualNanos)>,
    stats: DcmiStats,
}

/// Snapshots do not keep the camera (its frame source is outside the bench).
impl Store for Dcmi {}

impl Dcmi {
    /// Puts `camera` on the interface's far end; `sampler` reads the board's pins.
    pub fn attach(&mut self, camera: Camera, sampler: Sampler) {
        self.camera = Some(camera);
        self.sampler = Some(sampler);
    }

    /// The camera, if one is attached.
    #[must_use]
    pub fn camera(&self) -> Option<&Camera> {
        self.camera.as_ref()
    }

    /// What happened on the interface.
    #[must_use]
    pub fn stats(&self) -> DcmiStats {
        let mut stats = self.stats;
        stats.frames_streamed = self.camera.as_ref().map_or(0, |c| c.frames_streamed);
        stats
    }

    /// Every frame captured whole, in order: the camera frame's number (the [`FrameSource`]
    /// index it showed) and the instant the interface raised `FRAME`.
    #[must_use]
    pub fn captured(&self) -> &[(u64, VirtualNanos)] {
        &self.captured
    }

    /// The inputs as last sampled.
    #[must_use]
    pub fn inputs(&self) -> DcmiInputs {
        self.inputs
    }

    /// Samples the board's pins (the SoC calls this before every call into this slot).
    pub fn sample(&mut self, mcu: &Stm32f427, clock_timer: Option<&ClockTimer>) {
        if let Some(sampler) = self.sampler {
            self.set_inputs(sampler(mcu, clock_timer));
        }
    }

    /// Sets the inputs directly (for a model test without a part); the sensors' pins go to the
    /// sensors at once, so their SCCB port sees them too.
    pub fn set_inputs(&mut self, inputs: DcmiInputs) {
        self.inputs = inputs;
        if let Some(camera) = &self.camera {
            camera.sensor.lock().set_pins(inputs.sensor);
        }
    }

    /// Fault: the camera stops now and for good (no VSYNC, no data); the interface sees a camera
    /// that has gone quiet.
    pub fn stop_camera(&mut self) {
        if let Some(camera) = &mut self.camera {
            camera.stopped = true;
        }
        self.stream = None;
    }

    fn cr(registers: &RegisterFile) -> u64 {
        registers.get(Register::Cr)
    }

    fn enabled(&self, registers: &RegisterFile) -> bool {
        self.inputs.clock_enabled && cr::ENABLE.is_set(Self::cr(registers))
    }

    fn set_flag(
        &mut self,
        flag: &'static rigless::soc::FieldSpec,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        let value = registers.get(Register::Ris) | flag.mask();
        registers.set(Register::Ris, value);
        self.refresh_interrupt(registers, context);
    }

    fn refresh_interrupt(&mut self, registers: &RegisterFile, context: &mut DeviceContext<'_>) {
        let pending = registers.get(Register::Ris) & registers.get(Register::Ier) & 0x1F;
        let level = Level::from(pending != 0);
        if level != self.interrupt {
            self.interrupt = level;
            context.interrupt(INTERRUPT, level);
        }
    }

    fn refresh_request(&mut self, context: &mut DeviceContext<'_>) {
        let level = Level::from(!self.fifo.is_empty());
        if level != self.request {
            self.request = level;
            context.request(DMA_REQUEST, level);
        }
    }

    fn push_byte(
        &mut self,
        byte: u8,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        let (word, count) = self.packing;
        let word = word | (u32::from(byte) << (8 * count));
        if count + 1 < 4 {
            self.packing = (word, count + 1);
            return;
        }
        self.packing = (0, 0);
        if self.fifo.len() >= FIFO_WORDS {
            self.stats.words_lost += 1;
            self.set_flag(ris::OVR_RIS, registers, context);
        } else {
            self.fifo.push_back(word);
            self.stats.words += 1;
        }
    }

    /// The interface's frame has been captured: `FRAME`, and in snapshot mode `CAPTURE` clears.
    fn frame_captured(
        &mut self,
        index: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        self.capture.active = false;
        self.captured.push((index, context.now()));
        self.packing = (0, 0);
        self.stats.frames_captured += 1;
        self.set_flag(ris::FRAME_RIS, registers, context);
        let control = Self::cr(registers);
        if cr::CM.is_set(control) {
            registers.set(Register::Cr, control & !cr::CAPTURE.mask());
        }
    }

    /// Builds the stream of the camera frame starting at `origin`, or `None` while the camera
    /// does not stream.
    fn next_stream(&mut self, origin: VirtualNanos, registers: &RegisterFile) -> Option<Stream> {
        let inputs = self.inputs;
        let camera = self.camera.as_mut()?;
        if camera.stopped {
            return None;
        }
        let (setup, hz) = {
            let sensor = camera.sensor.lock();
            (sensor.stream()?, sensor.clock_hz()?)
        };
        if let Some(scene) = camera.source.frame(camera.frames_streamed, origin.0) {
            camera.scene = Some(scene);
        }
        let scene = camera.scene.as_ref()?;
        let index = camera.frames_streamed;
        camera.frames_streamed += 1;
        let control = Self::cr(registers);
        Some(build_stream(
            index, &setup, inputs, scene, hz, origin, control,
        ))
    }

    /// Runs the interface and its camera up to `now`.
    fn advance(&mut self, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        let now = context.now();
        if let Some(camera) = &self.camera {
            camera.sensor.lock().observe(now, self.inputs.sensor);
        }
        if self.camera.is_none() {
            return;
        }
        if self.stream.is_none() {
            // Not streaming: a stream starts at a sample that finds the camera set up.
            self.stream = self.next_stream(now, registers);
        }
        while let Some(stream) = self.stream.take() {
            if !self.camera_runs() {
                break;
            }
            match self.step(stream, now, registers, context) {
                Ok(next) => self.stream = Some(next),
                Err(Some(next)) => {
                    self.stream = Some(next);
                    break;
                }
                Err(None) => break,
            }
        }
        self.schedule(registers, context);
    }

    fn camera_runs(&self) -> bool {
        self.camera
            .as_ref()
            .is_some_and(|c| !c.stopped && c.sensor.lock().stream().is_some())
    }

    /// One step of `stream` due by `now`: `Ok` with the stream moved on, `Err(Some)` when nothing
    /// more is due, `Err(None)` when the camera stopped streaming.
    fn step(
        &mut self,
        mut s: Stream,
        now: VirtualNanos,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> Result<Stream, Option<Stream>> {
        let enabled = self.enabled(registers);
        match s.phase {
            Phase::Before => {
                if s.at(s.frame_start) > now {
                    return Err(Some(s));
                }
                s.phase = Phase::Within;
                self.capture.line = 0;
                self.packing = (0, 0);
                let control = Self::cr(registers);
                self.capture.active = false;
                if enabled
                    && cr::CAPTURE.is_set(control)
                    && !cr::ESS.is_set(control)
                    && !cr::JPEG.is_set(control)
                {
                    let every = match cr::FCRC.get(control) {
                        0 => 1,
                        1 => 2,
                        _ => 4,
                    };
                    self.capture.active = self.capture.counted.is_multiple_of(every);
                    self.capture.counted += 1;
                } else {
                    self.capture.counted = 0;
                }
                Ok(s)
            }
            Phase::Within => {
                if let Some(line) = s.lines.get(s.line) {
                    let due = s.clocks_by(now).saturating_sub(line.start);
                    let upto = usize::try_from(due)
                        .unwrap_or(usize::MAX)
                        .min(line.bytes.len());
                    if s.byte < upto {
                        let (first, last) = self.window(registers, line.bytes.len());
                        for k in s.byte..upto {
                            if self.capture.active && k >= first && k < last {
                                let byte = line.bytes[k];
                                self.push_byte(byte, registers, context);
                                if self.edm(registers) != 0 {
                                    self.push_byte(0, registers, context);
                                }
                            }
                        }
                        s.byte = upto;
                        self.refresh_request(context);
                    }
                    let end = line.start + line.bytes.len() as u64;
                    if s.at(end) > now {
                        return Err(Some(s));
                    }
                    // HSYNC turns active: the line ends.
                    if enabled {
                        self.set_flag(ris::LINE_RIS, registers, context);
                    }
                    if self.capture.active && self.crop(registers) {
                        let window = registers.get(Register::Cwstrt);
                        let size = registers.get(Register::Cwsize);
                        let last = cwstrt::VST.get(window) + cwsize::VLINE.get(size);
                        if u64::from(self.capture.line) == last {
                            self.frame_captured(s.index, registers, context);
                        }
                    }
                    self.capture.line += 1;
                    s.line += 1;
                    s.byte = 0;
                    return Ok(s);
                }
                if s.at(s.frame_end) > now {
                    return Err(Some(s));
                }
                // VSYNC turns active: the frame ends.
                if enabled {
                    self.set_flag(ris::VSYNC_RIS, registers, context);
                }
                if self.capture.active {
                    self.frame_captured(s.index, registers, context);
                }
                s.phase = Phase::After;
                Ok(s)
            }
            Phase::After => {
                let next = s.at(s.period);
                if next > now {
                    return Err(Some(s));
                }
                self.next_stream(next, registers).ok_or(None)
            }
        }
    }

    fn edm(&self, registers: &RegisterFile) -> u64 {
        cr::EDM.get(Self::cr(registers))
    }

    fn crop(&self, registers: &RegisterFile) -> bool {
        cr::CROP.is_set(Self::cr(registers))
    }

    /// The pixel clocks of the current line to take: all of them, or the crop window's, if the
    /// line is inside the window.
    fn window(&self, registers: &RegisterFile, len: usize) -> (usize, usize) {
        if !self.crop(registers) {
            return (0, len);
        }
        let start = registers.get(Register::Cwstrt);
        let size = registers.get(Register::Cwsize);
        let first_line = cwstrt::VST.get(start);
        let last_line = first_line + cwsize::VLINE.get(size);
        if !(first_line..=last_line).contains(&u64::from(self.capture.line)) {
            return (0, 0);
        }
        let first = cwstrt::HOFFCNT.get(start) as usize;
        let count = cwsize::CAPCNT.get(size) as usize + 1;
        (first.min(len), (first + count).min(len))
    }

    /// Wakes the model at the next instant something happens on the bus: at every eighth word of
    /// a line being captured, a line's end, a frame's edges; or to sample the pins while the
    /// camera does not stream.
    fn schedule(&mut self, registers: &RegisterFile, context: &mut DeviceContext<'_>) {
        let now = context.now();
        let at = match &self.stream {
            Some(s) => match s.phase {
                Phase::Before => s.at(s.frame_start),
                Phase::Within => match s.lines.get(s.line) {
                    Some(line) => {
                        let end = line.bytes.len();
                        let chunk = if self.capture.active {
                            // Pixel clocks of eight words: four bytes, or two half-words, each.
                            let per_word = if self.edm(registers) == 0 { 4 } else { 2 };
                            (s.byte + per_word * FIFO_WORDS).min(end)
                        } else {
                            end
                        };
                        s.at(line.start + chunk as u64)
                    }
                    None => s.at(s.frame_end),
                },
                Phase::After => s.at(s.period),
            },
            None => match &self.camera {
                Some(camera) if !camera.stopped => {
                    let close = camera.sensor.lock().needs_close_watch();
                    VirtualNanos(now.0 + if close { CLOSE_WATCH_NS } else { WATCH_NS })
                }
                _ => return,
            },
        };
        let at = VirtualNanos(at.0.max(now.0 + 1));
        if self.event.is_some_and(|(_, when)| when == at) {
            return;
        }
        let id = context.schedule(at);
        self.event = Some((id, at));
    }

    fn status(&self, now: VirtualNanos) -> u64 {
        let (hsync, vsync) = match &self.stream {
            Some(s) if s.phase == Phase::Within => {
                let c = s.clocks_by(now);
                let in_line = s
                    .lines
                    .get(s.line)
                    .is_some_and(|l| c >= l.start && c < l.start + l.bytes.len() as u64);
                (!in_line, false)
            }
            _ => (true, true),
        };
        let mut value = 0;
        if hsync {
            value |= sr::HSYNC.mask();
        }
        if vsync {
            value |= sr::VSYNC.mask();
        }
        if !self.fifo.is_empty() {
            value |= sr::FNE.mask();
        }
        value
    }
}

/// The interface's view of one camera frame: its frame edges and lines, through the polarities
/// and the sampling edge `control` sets and the data lines `inputs` connects.
fn build_stream(
    index: u64,
    setup: &StreamSetup,
    inputs: DcmiInputs,
    scene: &StereoImage,
    hz: u64,
    origin: VirtualNanos,
    control: u64,
) -> Stream {
    let line_clocks = tcm8230::LINE_CLOCKS;
    let active = tcm8230::ACTIVE_LINES * line_clocks;
    let period = setup.frame_lines * line_clocks;
    // The camera's lines: output line j at line period j * 480 / h, its 2w bytes at the start.
    let width = 2 * setup.width;
    let mut camera_lines: Vec<(u64, Option<Vec<u8>>)> = Vec::with_capacity(setup.height);
    for j in 0..setup.height {
        let (left, right) = scene.rows(j, setup.width, setup.height);
        let bytes = cpld::merge_line(inputs.cpld, setup, &left, &right);
        camera_lines.push((setup.line_period(j) * line_clocks, bytes));
    }
    // The camera drives HSYNC/VSYNC low during blanking ([SB] dcmi.c: both active low for the
    // TCM8230); `HSPOL`/`VSPOL` set (active high) make the interface read them the other way.
    let h_inverted = cr::HSPOL.is_set(control);
    let v_inverted = cr::VSPOL.is_set(control);
    // `PCKPOL` set: rising edge. The sensor launches on the rising edge when its bit is set.
    let wrong_edge = cr::PCKPOL.is_set(control) == setup.launch_on_rising;
    let (frame_start, frame_end) = if v_inverted {
        (active, period)
    } else {
        (0, active)
    };
    let mut lines = Vec::new();
    if inputs.sync_connected {
        // Valid (non-blanking) intervals of the camera's HSYNC within the interface's frame.
        let mut valid: Vec<(u64, u64, Option<&Vec<u8>>)> = camera_lines
            .iter()
            .map(|(start, bytes)| (*start, *start + width as u64, bytes.as_ref()))
            .filter(|(start, _, _)| *start < active)
            .collect();
        if h_inverted {
            // The interface's lines are the camera's horizontal blanking.
            let mut blank = Vec::new();
            let mut at = 0;
            for (start, end, _) in &valid {
                if *start > at {
                    blank.push((at, *start, None));
                }
                at = *end;
            }
            if at < period {
                blank.push((at, period, None));
            }
            valid = blank;
        }
        for (start, end, bytes) in valid {
            let (start, end) = (start.max(frame_start), end.min(frame_end));
            if start >= end {
                continue;
            }
            let len = (end - start) as usize;
            // The camera drives 0x00 during blanking and the CPLD nothing in a mode it lacks.
            let mut taken: Vec<u8> = match bytes {
                Some(b) => b.iter().copied().take(len).collect(),
                None => vec![0; len],
            };
            taken.resize(len, 0);
            if wrong_edge {
                taken.rotate_right(1);
                taken[0] = 0;
            }
            for b in &mut taken {
                *b &= inputs.data_mask;
            }
            lines.push(Line {
                start,
                bytes: taken,
            });
        }
    }
    Stream {
        index,
        hz,
        origin,
        period,
        frame_start,
        frame_end,
        lines,
        phase: Phase::Before,
        line: 0,
        byte: 0,
    }
}

impl Device for Dcmi {
    type Register = Register;

    fn read(
        &mut self,
        register: Register,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) -> Option<u64> {
        if !self.inputs.clock_enabled {
            self.tell_clock(context);
            return Some(0);
        }
        self.advance(registers, context);
        match register {
            Register::Dr => {
                self.stats.reads += 1;
                let word = self.fifo.pop_front().unwrap_or(0);
                self.refresh_request(context);
                Some(u64::from(word))
            }
            Register::Sr => Some(self.status(context.now())),
            Register::Mis => Some(registers.get(Register::Ris) & registers.get(Register::Ier)),
            _ => None,
        }
    }

    fn write(
        &mut self,
        register: Register,
        value: u64,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        if !self.inputs.clock_enabled {
            // The write does not reach an unclocked interface: the register keeps what it held.
            self.tell_clock(context);
            registers.set(register, self.shadow[register as usize]);
            return;
        }
        match register {
            Register::Icr => {
                let clear = value
                    & (icr::FRAME_ISC.mask()
                        | icr::OVR_ISC.mask()
                        | icr::ERR_ISC.mask()
                        | icr::VSYNC_ISC.mask()
                        | icr::LINE_ISC.mask());
                let kept = registers.get(Register::Ris) & !clear;
                registers.set(Register::Ris, kept);
                registers.set(Register::Icr, 0);
            }
            // Disabled: the FIFO and the capture in progress are dropped.
            Register::Cr if !cr::ENABLE.is_set(value) => {
                self.fifo.clear();
                self.packing = (0, 0);
                self.capture = Capture::default();
                self.refresh_request(context);
            }
            _ => {}
        }
        for r in Register::ALL {
            self.shadow[r as usize] = registers.get(r);
        }
        self.refresh_interrupt(registers, context);
        self.advance(registers, context);
    }

    fn on_event(
        &mut self,
        event: EventId,
        registers: &mut RegisterFile,
        context: &mut DeviceContext<'_>,
    ) {
        if self.event.is_some_and(|(id, _)| id == event) {
            self.event = None;
        }
        self.advance(registers, context);
    }

    /// The part restarted: the interface is back at reset (its registers already are); the
    /// camera is the board's and runs on, and is picked up again at the next access.
    fn reset(&mut self) {
        self.fifo.clear();
        self.packing = (0, 0);
        self.capture = Capture::default();
        self.request = Level::Low;
        self.interrupt = Level::Low;
        self.event = None;
        self.told_clock = false;
        self.shadow = [0; Register::ALL.len()];
    }
}

impl Dcmi {
    fn tell_clock(&mut self, context: &mut DeviceContext<'_>) {
        if !self.told_clock {
            self.told_clock = true;
            context.tell(
                "CR",
                "RM0090 6.3.11: DCMI accessed with RCC_AHB2ENR.DCMIEN clear (ignored, reads 0)",
            );
        }
    }

    /// Kicks the camera's timeline (the board calls this once after attaching, so the camera's
    /// pins are watched from the start).
    pub fn start(&mut self, registers: &mut RegisterFile, context: &mut DeviceContext<'_>) {
        self.advance(registers, context);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::{PIXELS, Recorded, STEREO_BYTES};
    use crate::tcm8230::{
        CLOCK_POLARITY_REVERSED, FORMAT_RGB565, REG_FORMAT, REG_FPS, SIZE_SUBQCIF,
    };
    use rigless::mcu::{Operate, Single};
    use rigless::soc::Width;
    use rigless::soc::stm32f427::builder;
    use rigless::soc::stm32f427::generated::DCMI;

    const HZ: u64 = 21_000_000;
    /// One camera frame at 21 MHz, ns.
    const FRAME_NS: u64 = 40_560_000;
    const CR: u64 = 0x00;
    const SR: u64 = 0x04;
    const RIS: u64 = 0x08;
    const IER: u64 = 0x0C;
    const MIS: u64 = 0x10;
    const ICR: u64 = 0x14;
    const CWSTRT: u64 = 0x20;
    const CWSIZE: u64 = 0x24;
    const DR: u64 = 0x28;
    /// The original board's set-up (\[SB\] dcmi.c): continuous, hardware sync, PIXCLK falling,
    /// HSYNC and VSYNC active low, all frames, 8 bits, crop on.
    const CR_ORIGINAL: u64 = 1 << 2 | 1 << 14;
    const CAPTURE: u64 = 1;

    fn scene(seed: u32) -> StereoImage {
        let mut left = Box::new([0u8; PIXELS]);
        let mut right = Box::new([0u8; PIXELS]);
        for i in 0..PIXELS {
            left[i] = ((i as u32 * 7 + seed) % 251) as u8;
            right[i] = ((i as u32 * 13 + 3 * seed) % 241) as u8;
        }
        StereoImage { left, right }
    }

    fn pins() -> DcmiInputs {
        DcmiInputs {
            sensor: SensorPins {
                extclk_hz: Some(HZ),
                reset_released: true,
            },
            cpld: Mode::PixelInterleave,
            clock_enabled: true,
            sync_connected: true,
            data_mask: 0xFF,
        }
    }

    struct Bench {
        single: Single<Dcmi>,
        sensor: SensorHandle,
        now: u64,
        /// Bytes read out of `DR` (the DMA's work in these tests).
        read: Vec<u8>,
    }

    impl Bench {
        /// A camera brought up as the original firmware does (reset pulse with the clock
        /// running, then 0x02 and 0x03 written), and the interface's `control` written
        /// without `CAPTURE`.
        fn new(frames: usize, fps: u8, format: u8, control: u64) -> Self {
            let sensor = SensorHandle::new();
            let images = (0..frames as u32).map(scene).collect();
            let dcmi = Dcmi {
                camera: Some(Camera::new(sensor.clone(), Box::new(Recorded::new(images)))),
                ..Dcmi::default()
            };
            let single = Single::new(builder(), "DCMI", dcmi).expect("the DCMI slot");
            let mut b = Self {
                single,
                sensor,
                now: 0,
                read: Vec::new(),
            };
            let mut held = pins();
            held.sensor.reset_released = false;
            b.single.model.set_inputs(held);
            b.single.drive(VirtualNanos(0), |m, r, c| m.start(r, c));
            b.run(20_000, false);
            b.single.model.set_inputs(pins());
            b.run(80_000, false);
            {
                let mut s = b.sensor.lock();
                let t = VirtualNanos(b.now);
                assert!(s.sccb_write_register(t, REG_FPS, fps));
                assert!(s.sccb_write_register(t, REG_FORMAT, format));
            }
            b.write(CWSTRT, 0);
            b.write(CWSIZE, (95 << 16) | 255);
            b.write(CR, control);
            b
        }

        fn original() -> Self {
            Self::new(4, 0x42, SIZE_SUBQCIF << 2, CR_ORIGINAL)
        }

        fn write(&mut self, offset: u64, value: u64) {
            self.single
                .write(
                    VirtualNanos(self.now),
                    DCMI.base + offset,
                    Width::W32,
                    value,
                )
                .expect("the DCMI takes the write");
        }

        fn get(&mut self, offset: u64) -> u64 {
            self.single
                .read(VirtualNanos(self.now), DCMI.base + offset, Width::W32)
                .expect("the DCMI answers")
        }

        /// Runs to `until` ns, reading `DR` while words wait if `drain`.
        fn run(&mut self, until: u64, drain: bool) {
            while let Some(at) = self.single.next_event() {
                if at.0 > until {
                    break;
                }
                self.now = at.0;
                self.single.advance_to(at);
                if drain {
                    while self.get(SR) & 4 != 0 {
                        let word = self.get(DR) as u32;
                        self.read.extend_from_slice(&word.to_le_bytes());
                    }
                }
            }
            self.now = until;
        }
    }

    #[test]
    fn continuous_capture_with_the_original_setup_delivers_each_scene_interleaved() {
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 4 * FRAME_NS, true);
        let stats = b.single.model.stats();
        assert!(stats.frames_captured >= 3, "{stats:?}");
        assert_eq!(stats.words_lost, 0);
        // The capture starts at the first frame start after CAPTURE; every frame captured is
        // one scene, whole and in order.
        let frames: Vec<&[u8]> = b.read.chunks(STEREO_BYTES).collect();
        let first = (0..4)
            .find(|k| scene(*k).interleaved()[..] == *frames[0])
            .expect("the first captured frame is one of the scenes");
        for (i, frame) in frames
            .iter()
            .enumerate()
            .take(stats.frames_captured as usize)
        {
            assert_eq!(
                *frame,
                &scene(first + i as u32).interleaved()[..],
                "frame {i}"
            );
        }
        assert_eq!(
            b.get(RIS) & 0b11001,
            0b11001,
            "FRAME, VSYNC and LINE raised"
        );
    }

    #[test]
    fn frames_come_at_the_sensors_rate_from_its_clock() {
        let mut b = Bench::original();
        let start = b.single.model.stats().frames_streamed;
        b.run(b.now + 1_000_000_000, false);
        // 21 MHz / (546 * 1,560) = 24.65 frames per second; at half rate, 12.3.
        assert_eq!(b.single.model.stats().frames_streamed - start, 24);
        let mut b = Bench::new(4, 0x42 | 0x80, SIZE_SUBQCIF << 2, CR_ORIGINAL);
        let start = b.single.model.stats().frames_streamed;
        b.run(b.now + 1_000_000_000, false);
        assert_eq!(b.single.model.stats().frames_streamed - start, 12);
    }

    #[test]
    fn snapshot_captures_one_frame_and_clears_capture() {
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | 1 << 1 | CAPTURE);
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.single.model.stats().frames_captured, 1);
        assert_eq!(b.read.len(), STEREO_BYTES);
        assert_eq!(b.get(CR) & CAPTURE, 0, "CAPTURE cleared by hardware");
    }

    #[test]
    fn every_other_frame_is_captured_with_fcrc_01() {
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | 1 << 8 | CAPTURE);
        b.run(b.now + 6 * FRAME_NS, true);
        let captured = b.single.model.stats().frames_captured;
        assert!(captured == 3, "{captured} frames of 6");
    }

    #[test]
    fn the_crop_window_takes_the_pixel_clocks_and_lines_it_names() {
        let mut b = Bench::original();
        // Lines 2 and 3, pixel clocks 4 ..= 11.
        b.write(CWSTRT, (2 << 16) | 4);
        b.write(CWSIZE, (1 << 16) | 7);
        b.write(CR, CR_ORIGINAL | 1 << 1 | CAPTURE);
        b.run(b.now + 2 * FRAME_NS, true);
        assert_eq!(b.read.len(), 16);
        let frame = b.single.model.stats().frames_streamed;
        let _ = frame;
        // Which scene the snapshot caught: the one whose line 2 matches.
        let hit = (0..4)
            .map(|k| scene(k).interleaved())
            .find(|f| f[2 * 256 + 4..2 * 256 + 12] == b.read[..8])
            .expect("line 2, clocks 4..12 of a scene");
        assert_eq!(&b.read[8..], &hit[3 * 256 + 4..3 * 256 + 12]);
    }

    #[test]
    fn a_stream_that_is_not_drained_overruns() {
        let mut b = Bench::original();
        b.write(IER, 1 << 1);
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 2 * FRAME_NS, false);
        let stats = b.single.model.stats();
        assert_eq!(stats.words, 8, "the FIFO holds eight words");
        assert!(stats.words_lost >= 6_144 - 8, "{stats:?}");
        assert_eq!(b.get(RIS) & 2, 2, "OVR");
        assert_eq!(b.get(MIS), 2);
        assert!(
            b.single
                .drain_interrupts()
                .iter()
                .any(|i| i.interrupt == 78 && i.level == Level::High)
        );
    }

    #[test]
    fn flags_interrupt_and_clear_as_the_manual_says() {
        let mut b = Bench::original();
        b.write(IER, 1 << 3); // VSYNC
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 2 * FRAME_NS, true);
        assert_eq!(
            b.get(MIS),
            1 << 3,
            "only the enabled flag is masked through"
        );
        assert_eq!(b.get(RIS) & 0b11001, 0b11001);
        let raised = b.single.drain_interrupts();
        assert!(raised.iter().any(|i| i.level == Level::High));
        b.write(ICR, 0x1F);
        assert_eq!(b.get(RIS), 0);
        assert!(
            b.single
                .drain_interrupts()
                .iter()
                .any(|i| i.level == Level::Low),
            "the interrupt falls with its flag"
        );
    }

    #[test]
    fn the_wrong_pixel_clock_edge_shifts_every_byte() {
        // The sensor launches on the rising edge (0x02 bit 1); PCKPOL = 1 samples on it too.
        let mut b = Bench::new(4, CLOCK_POLARITY_REVERSED, SIZE_SUBQCIF << 2, CR_ORIGINAL);
        b.write(CR, CR_ORIGINAL | 1 << 5 | 1 << 1 | CAPTURE);
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.read.len(), STEREO_BYTES);
        let matched = (0..4).any(|k| scene(k).interleaved()[..] == b.read[..]);
        assert!(
            !matched,
            "a frame sampled on the launching edge is not the scene"
        );
        let shifted = (0..4).any(|k| scene(k).interleaved()[..255] == b.read[1..256]);
        assert!(shifted, "each byte is its predecessor");
    }

    #[test]
    fn a_wrong_sync_polarity_captures_the_blanking() {
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | 1 << 6 | 1 << 1 | CAPTURE); // HSPOL active high
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.read.len(), STEREO_BYTES);
        assert!(
            b.read.iter().all(|&x| x == 0),
            "the blanking, not the picture"
        );
    }

    #[test]
    fn rgb565_sensors_do_not_give_the_luminance_frame() {
        let mut b = Bench::new(4, 0x42, SIZE_SUBQCIF << 2 | FORMAT_RGB565, CR_ORIGINAL);
        b.write(CR, CR_ORIGINAL | 1 << 1 | CAPTURE);
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.read.len(), STEREO_BYTES);
        assert!((0..4).all(|k| scene(k).interleaved()[..] != b.read[..]));
    }

    #[test]
    fn nothing_without_the_interface_clock() {
        let mut b = Bench::original();
        let mut off = pins();
        off.clock_enabled = false;
        b.single.model.set_inputs(off);
        b.write(CR, CR_ORIGINAL | CAPTURE);
        assert_eq!(b.get(CR), 0, "an unclocked interface reads 0");
        b.single.model.set_inputs(pins());
        assert_eq!(b.get(CR) & CAPTURE, 0, "and did not take the write");
        b.run(b.now + 3 * FRAME_NS, true);
        assert!(b.read.is_empty());
        assert!(
            b.single
                .drain_told()
                .iter()
                .any(|t| t.reason.contains("DCMIEN"))
        );
    }

    #[test]
    fn no_stream_without_clock_reset_or_setup() {
        // Set up but the output never switched on: no VSYNC, nothing captured.
        let mut b = Bench::new(
            4,
            0x42,
            tcm8230::OUTPUT_OFF | SIZE_SUBQCIF << 2,
            CR_ORIGINAL,
        );
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 3 * FRAME_NS, true);
        assert!(b.read.is_empty());
        assert_eq!(b.get(RIS), 0, "no VSYNC, no LINE");
        // Clock taken away from a streaming camera: the stream stops.
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 2 * FRAME_NS, true);
        let streamed = b.single.model.stats().frames_streamed;
        let mut off = pins();
        off.sensor.extclk_hz = None;
        b.single.model.set_inputs(off);
        b.run(b.now + 3 * FRAME_NS, true);
        assert!(b.single.model.stats().frames_streamed <= streamed + 1);
        // D6/D7 not connected: those bits read 0.
        let mut b = Bench::original();
        let mut half = pins();
        half.data_mask = 0x3F;
        b.single.model.set_inputs(half);
        b.write(CR, CR_ORIGINAL | 1 << 1 | CAPTURE);
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.read.len(), STEREO_BYTES);
        assert!(b.read.iter().all(|&x| x & 0xC0 == 0));
    }

    #[test]
    fn a_stopped_camera_sends_no_more_vsync() {
        let mut b = Bench::original();
        b.write(CR, CR_ORIGINAL | CAPTURE);
        b.run(b.now + 2 * FRAME_NS, true);
        b.single.model.stop_camera();
        b.write(ICR, 0x1F);
        b.run(b.now + 3 * FRAME_NS, true);
        assert_eq!(b.get(RIS), 0);
        assert!(b.single.next_event().is_none(), "nothing left to happen");
    }
}
