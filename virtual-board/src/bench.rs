//! The harness: load an ELF onto a board, run it for virtual time, watch it.
//!
//! [`run`] runs one board; [`run_pair`] runs two in lockstep (both stop at every multiple of a
//! quantum and wait for each other, so bytes crossing a [`crate::link`] arrive at the same
//! virtual instant on every run). At every stop the bench drains the firmware's defmt log
//! ([`crate::rtt`]) and calls the test's [`Probe`].
//!
//! It fails (records a violation in [`Outcome::violations`]) a run that reaches a peripheral the
//! board's real part lacks or stores into memory it lacks, and records every arrival at the
//! panic handler, the HardFault handler, the NMI handler or the `DefaultHandler` in [`Outcome::faults`].

use std::sync::{Arc, Condvar, Mutex};

use rigless::emulator::{self, Driver, Hit, Host, Settled, Start, Stop, Watch};
use rigless::image::Image;
use rigless::machine::Board;
use rigless::mcu::Mcu;
use rigless::session::Session;
use rigless::time::VirtualNanos;

use crate::firmware::Firmware;
use crate::rtt::RttLog;
use crate::soc::Soc;
use crate::stack::{StackScan, StackUse};

/// A board the bench can run: a rigless board whose one target is our [`Soc`].
pub trait BenchBoard: Board + Sized + 'static {
    /// The board's SoC.
    fn soc(&self) -> &Soc;
    /// The board's SoC, mutably.
    fn soc_mut(&mut self) -> &mut Soc;
    /// Called by the bench at every stop before the probe: the board moves its chips' signals
    /// on to `now` (a sensor's new sample, a pin level). Nothing by default.
    fn advance(&mut self, now: VirtualNanos) {
        let _ = now;
    }
    /// What the board's flash holds beside the firmware at power-on, `(address, bytes)`: what
    /// earlier runs left there, such as saved parameters ([`crate::flash`]). The bench places
    /// it before the first instruction. Nothing by default.
    fn flash_contents(&self) -> Vec<(u64, Vec<u8>)> {
        Vec::new()
    }
}

/// What a probe tells the bench after a stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Run on to the next stop.
    Continue,
    /// End the run here.
    Stop,
}

/// What a stop lends the probe.
pub struct At<'a, B: BenchBoard> {
    /// Virtual time now, ns.
    pub now: u64,
    /// The session: the board (`session.board_mut()`), its reports.
    pub session: &'a mut Session<B>,
    /// The core's memory and interrupt lines.
    pub host: &'a mut dyn Host,
    /// The firmware's log so far.
    pub log: &'a RttLog,
    /// Faults so far (panics, HardFaults).
    pub faults: &'a [FirmwareFault],
}

impl<B: BenchBoard> At<'_, B> {
    /// The board.
    pub fn board(&mut self) -> &mut B {
        self.session.board_mut()
    }
}

/// A test's eyes and hands at every stop.
pub trait Probe<B: BenchBoard>: Send + 'static {
    /// Called at every stop; says whether to go on.
    fn at(&mut self, at: &mut At<'_, B>) -> Flow;

    /// Called at every hit on what the test itself watches (`session.watch`), between two
    /// instructions, with the core's memory: a fault injected at an exact instruction. Nothing
    /// by default.
    fn hit(&mut self, hit: &Hit, session: &mut Session<B>, host: &mut dyn Host) {
        let _ = (hit, session, host);
    }
}

/// A closure as a probe.
pub struct Closure<F>(pub F);

impl<B: BenchBoard, F> Probe<B> for Closure<F>
where
    F: FnMut(&mut At<'_, B>) -> Flow + Send + 'static,
{
    fn at(&mut self, at: &mut At<'_, B>) -> Flow {
        (self.0)(at)
    }
}

/// A probe that only watches.
#[derive(Debug, Default, Clone, Copy)]
pub struct Watching;

impl<B: BenchBoard> Probe<B> for Watching {
    fn at(&mut self, _at: &mut At<'_, B>) -> Flow {
        Flow::Continue
    }
}

/// The firmware reached a fault handler.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FirmwareFault {
    /// Virtual time, ns.
    pub at_ns: u64,
    /// The handler's symbol.
    pub handler: String,
}

/// How to run one board.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Virtual time to run, ns.
    pub until_ns: u64,
    /// Stop (drain the log, call the probe) every this many ns.
    pub step_ns: u64,
}

impl Options {
    /// Run for `seconds` of virtual time, stopping every millisecond.
    #[must_use]
    pub fn seconds(seconds: f64) -> Self {
        Self {
            until_ns: (seconds * 1e9) as u64,
            step_ns: 1_000_000,
        }
    }

    /// The same, stopping every `step_us` microseconds.
    #[must_use]
    pub fn step_us(self, step_us: u64) -> Self {
        Self {
            step_ns: step_us * 1_000,
            ..self
        }
    }
}

/// What a run leaves.
pub struct Outcome<B: BenchBoard, P> {
    /// The session: the board as the run left it, rigless's reports (unmapped, resets...).
    pub session: Session<B>,
    /// The probe, with what it kept.
    pub probe: P,
    /// The firmware's defmt log.
    pub log: RttLog,
    /// Arrivals at the panic, HardFault, NMI or default (unbound exception) handler.
    pub faults: Vec<FirmwareFault>,
    /// Accesses the real part could not have made.
    pub violations: Vec<String>,
    /// Virtual time the run ended at, ns.
    pub end_ns: u64,
    /// Wall time of the run, s.
    pub wall_s: f64,
    /// The stack's low-water mark over the run ([`crate::stack`]), if it was ever seen painted.
    pub stack: Option<StackUse>,
}

impl<B: BenchBoard, P> Outcome<B, P> {
    /// The board.
    pub fn board(&self) -> &B {
        self.session.board()
    }

    /// Everything a failing test should print: the log, faults, violations, resets, gaps.
    #[must_use]
    pub fn report(&self) -> String {
        let mut out = format!(
            "--- run of {} ended at {:.3} ms virtual ({:.2} s wall) ---\n",
            self.session.board().name(),
            self.end_ns as f64 / 1e6,
            self.wall_s
        );
        out += &self.log.text();
        for fault in &self.faults {
            out += &format!(
                "FAULT at {:.3} ms: {}\n",
                fault.at_ns as f64 / 1e6,
                fault.handler
            );
        }
        for violation in &self.violations {
            out += &format!("VIOLATION: {violation}\n");
        }
        for reset in self.session.resets() {
            out += &format!("reset: {reset:?}\n");
        }
        for unmapped in self.session.unmapped() {
            out += &format!("unmapped: {unmapped}\n");
        }
        out
    }

    /// Panics with the report if the run faulted or broke the part's limits, or if a `real`
    /// image went deeper into its stack than `xtask/budgets.toml` records ([`crate::stack`]).
    pub fn assert_clean(&self) {
        assert!(
            self.faults.is_empty() && self.violations.is_empty(),
            "the firmware faulted or reached what its part lacks\n{}",
            self.report()
        );
        if let Some(stack) = &self.stack
            && let Some(package) = &stack.real_image
        {
            let recorded = crate::stack::recorded_use(package).unwrap_or_else(|e| panic!("{e}"));
            println!(
                "stack: {package} used {} of {} B (recorded {recorded} B)",
                stack.used(),
                stack.reserve
            );
            assert!(
                stack.used() <= recorded,
                "{package} used {} B of stack, xtask/budgets.toml records {recorded} B: record \
                 the new figure there (its margin is `cargo xtask size`'s)\n{}",
                stack.used(),
                self.report()
            );
        }
    }

    /// Whether any log line contains `text`.
    #[must_use]
    pub fn logged(&self, text: &str) -> bool {
        self.log.lines().iter().any(|l| l.text.contains(text))
    }
}

/// Stops of two boards in lockstep: each waits at every quantum for the other.
#[derive(Debug, Default)]
pub struct Lockstep {
    state: Mutex<LockState>,
    turn: Condvar,
}

#[derive(Debug, Default)]
struct LockState {
    generation: u64,
    arrived: u32,
    ended: bool,
}

impl Lockstep {
    /// Waits for the other side; `false` once the other side has ended.
    fn wait(&self) -> bool {
        let mut state = self.state.lock().expect("lockstep lock");
        if state.ended {
            return false;
        }
        state.arrived += 1;
        if state.arrived == 2 {
            state.arrived = 0;
            state.generation += 1;
            self.turn.notify_all();
            return true;
        }
        let generation = state.generation;
        while state.generation == generation && !state.ended {
            state = self.turn.wait(state).expect("lockstep lock");
        }
        !state.ended || state.generation != generation
    }

    fn end(&self) {
        let mut state = self.state.lock().expect("lockstep lock");
        state.ended = true;
        self.turn.notify_all();
    }
}

/// Something a barrier releases: one receive side of a link (see [`crate::link`]).
pub trait OnBarrier: Send + Sync {
    /// Both boards have reached `now` ns.
    fn barrier(&self, now: u64);
}

struct BenchDriver<B: BenchBoard, P> {
    probe: P,
    log: RttLog,
    faults: Vec<FirmwareFault>,
    violations: Vec<String>,
    handlers: Vec<(u64, String)>,
    missing_ram: crate::soc::Range,
    until_ns: u64,
    step_ns: u64,
    end_ns: u64,
    lockstep: Option<Arc<Lockstep>>,
    on_barrier: Vec<Arc<dyn OnBarrier>>,
    stack: Option<StackScan>,
    marker: std::marker::PhantomData<fn() -> B>,
}

const MAX_VIOLATIONS: usize = 20;

impl<B: BenchBoard, P: Probe<B>> Driver<B> for BenchDriver<B, P> {
    fn on_settled(&mut self, session: &mut Session<B>, host: &mut dyn Host, settled: Settled) {
        match settled {
            Settled::Access { access, .. } => {
                let soc = session.board().soc();
                let bus = soc.bus();
                if let Some(slot) = bus.slot_at(access.address) {
                    let name = bus.slots()[slot].peripheral().name;
                    if soc.part.lacks(name) && self.violations.len() < MAX_VIOLATIONS {
                        self.violations.push(format!(
                            "{:?} of {name} at {:#x} (pc {:#x?}, t = {:.3} ms): the {} has no {name}",
                            access.kind,
                            access.address,
                            access.program_counter,
                            access.virtual_time.0 as f64 / 1e6,
                            soc.part.name()
                        ));
                    }
                }
            }
            Settled::Hit(hit) => {
                if self.missing_ram.holds(hit.address, 1) {
                    if self.violations.len() < MAX_VIOLATIONS {
                        self.violations.push(format!(
                            "store at {:#x} ({}), t = {:.3} ms",
                            hit.address,
                            self.missing_ram.name,
                            hit.at.0 as f64 / 1e6
                        ));
                    }
                } else if let Some((_, name)) = self
                    .handlers
                    .iter()
                    .find(|(address, _)| *address == hit.address)
                {
                    self.faults.push(FirmwareFault {
                        at_ns: hit.at.0,
                        handler: name.clone(),
                    });
                } else {
                    self.probe.hit(&hit, session, host);
                }
            }
            _ => {}
        }
    }

    fn on_stop(
        &mut self,
        session: &mut Session<B>,
        stop: Stop,
        host: &mut dyn Host,
    ) -> Option<VirtualNanos> {
        let now = stop.at.0;
        self.end_ns = now;
        session.board_mut().advance(stop.at);
        self.log.drain(host, now);
        let flow = self.probe.at(&mut At {
            now,
            session,
            host,
            log: &self.log,
            faults: &self.faults,
        });
        let mut go_on = flow == Flow::Continue && now < self.until_ns;
        if let Some(lockstep) = &self.lockstep {
            if !go_on {
                lockstep.end();
            } else if lockstep.wait() {
                for released in &self.on_barrier {
                    released.barrier(now);
                }
            } else {
                go_on = false;
            }
        }
        // The next multiple of the step: a stop lands a little after its instant (an
        // instruction boundary), and the next is not pushed later by that.
        if let Some(stack) = &mut self.stack {
            stack.at_stop(now, host, !go_on);
        }
        let step = self.step_ns.max(1);
        let next = (now / step + 1) * step;
        go_on.then(|| VirtualNanos(next.min(self.until_ns)))
    }
}

/// One board with its firmware and probe, ready to run.
pub struct Setup<B: BenchBoard, P> {
    /// The board.
    pub board: B,
    /// The firmware it runs.
    pub firmware: Firmware,
    /// The test's probe.
    pub probe: P,
}

/// A run ready to start: the session, its driver, the images (the firmware, then the flash
/// contents).
type Prepared<B, P> = (Session<B>, BenchDriver<B, P>, Vec<Image>);

fn prepare<B: BenchBoard, P: Probe<B>>(
    setup: Setup<B, P>,
    options: Options,
    lockstep: Option<Arc<Lockstep>>,
    on_barrier: Vec<Arc<dyn OnBarrier>>,
) -> Result<Prepared<B, P>, String> {
    let Setup {
        board,
        firmware,
        probe,
    } = setup;
    let part = board.soc().part;
    firmware.check_memory(part)?;
    let flash = part.memory()[0];
    let mut images = Vec::new();
    for (address, bytes) in board.flash_contents() {
        if !flash.holds(address, bytes.len() as u64) {
            return Err(format!(
                "flash contents at {address:#x}+{:#x} lie outside the {}'s flash",
                bytes.len(),
                part.name()
            ));
        }
        let name = format!("flash@{address:#x}");
        images.push(
            Image::new(std::path::Path::new(&name), bytes, Some(address))
                .map_err(|e| format!("{name}: {e}"))?,
        );
    }
    let mut session = Session::new(Box::new(board), 0, VirtualNanos(options.step_ns))
        .map_err(|e| format!("session: {e}"))?;
    let mut handlers = Vec::new();
    for (name, address) in firmware.symbols_containing("rust_begin_unwind") {
        handlers.push((address, name.to_owned()));
    }
    for name in [
        "HardFault",
        "HardFault_",
        "HardFaultTrampoline",
        "NonMaskableInt",
        "DefaultHandler",
    ] {
        if let Some(address) = firmware.symbol(name) {
            handlers.push((address, name.to_owned()));
        }
    }
    handlers.sort();
    handlers.dedup_by_key(|(address, _)| *address);
    for (address, _) in &handlers {
        session.watch(Watch::Instruction(*address));
    }
    let missing_ram = part.missing_ram();
    session.watch(Watch::Writes {
        address: missing_ram.base,
        length: missing_ram.size,
    });
    let log = RttLog::new(firmware.symbol("_SEGGER_RTT"), firmware.defmt_table()?);
    let stack = StackScan::new(&firmware);
    let driver = BenchDriver {
        probe,
        log,
        faults: Vec::new(),
        violations: Vec::new(),
        handlers,
        missing_ram,
        until_ns: options.until_ns,
        step_ns: options.step_ns,
        end_ns: 0,
        lockstep,
        on_barrier,
        stack,
        marker: std::marker::PhantomData,
    };
    images.insert(0, firmware.image);
    Ok((session, driver, images))
}

fn finish<B: BenchBoard, P: Probe<B>>(
    finished: emulator::Finished<B, BenchDriver<B, P>>,
    wall_s: f64,
) -> Outcome<B, P> {
    let driver = finished.driver;
    Outcome {
        session: finished.session,
        probe: driver.probe,
        log: driver.log,
        faults: driver.faults,
        violations: driver.violations,
        end_ns: driver.end_ns,
        wall_s,
        stack: driver.stack.as_ref().and_then(StackScan::result),
    }
}

/// Runs one board.
///
/// # Errors
/// The image does not fit the part, or rigless refuses the run.
pub fn run<B: BenchBoard, P: Probe<B>>(
    setup: Setup<B, P>,
    options: Options,
) -> Result<Outcome<B, P>, String> {
    let (session, driver, images) = prepare(setup, options, None, Vec::new())?;
    let started = std::time::Instant::now();
    let finished = emulator::run(session, &Start::new(&images), driver)
        .map_err(|e| format!("emulator: {e}"))?;
    Ok(finish(finished, started.elapsed().as_secs_f64()))
}

/// Runs two boards in lockstep, stopping both at every `options.step_ns` (the quantum; bytes
/// between them cross at those instants, see [`crate::link`]). `on_barrier_a` is what board A
/// releases once both have reached a quantum (its receive side of each link), `on_barrier_b`
/// board B's.
///
/// # Errors
/// Either image does not fit its part, or rigless refuses a run.
#[allow(clippy::type_complexity)]
pub fn run_pair<A, PA, B, PB>(
    a: Setup<A, PA>,
    b: Setup<B, PB>,
    options: Options,
    on_barrier_a: Vec<Arc<dyn OnBarrier>>,
    on_barrier_b: Vec<Arc<dyn OnBarrier>>,
) -> Result<(Outcome<A, PA>, Outcome<B, PB>), String>
where
    A: BenchBoard + Send,
    PA: Probe<A>,
    B: BenchBoard + Send,
    PB: Probe<B>,
{
    let lockstep = Arc::new(Lockstep::default());
    // Each side releases only what it receives, on its own thread after the barrier, so what a
    // board hears does not depend on how the two threads interleave.
    let (session_a, driver_a, images_a) =
        prepare(a, options, Some(lockstep.clone()), on_barrier_a)?;
    let (session_b, driver_b, images_b) =
        prepare(b, options, Some(lockstep.clone()), on_barrier_b)?;
    let started = std::time::Instant::now();
    let (done_a, done_b) = std::thread::scope(|scope| {
        let lock_a = lockstep.clone();
        let thread_a = scope.spawn(move || {
            let done = emulator::run(session_a, &Start::new(&images_a), driver_a);
            lock_a.end();
            done
        });
        let lock_b = lockstep.clone();
        let thread_b = scope.spawn(move || {
            let done = emulator::run(session_b, &Start::new(&images_b), driver_b);
            lock_b.end();
            done
        });
        (thread_a.join(), thread_b.join())
    });
    let wall_s = started.elapsed().as_secs_f64();
    let done_a = done_a
        .map_err(|_| "board A's run panicked".to_owned())?
        .map_err(|e| format!("emulator (A): {e}"))?;
    let done_b = done_b
        .map_err(|_| "board B's run panicked".to_owned())?
        .map_err(|e| format!("emulator (B): {e}"))?;
    Ok((finish(done_a, wall_s), finish(done_b, wall_s)))
}
