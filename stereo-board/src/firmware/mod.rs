//! RTIC 2 application of the stereo-board firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell around [`stereo_board::app`]: the tasks below mirror `app::TASKS` and each body
//! is one call into [`StereoBoardApp`]. Pins, peripherals, clocks and rates come from the board
//! definition, [`stereo_board::board`]. What differs between flavours is in one module each,
//! as on the autopilot: [`real`] (own cameras, board clock) and [`lockstep`] (`hil`, `qemu`:
//! frames from the host, world time), selected as `flavour`; each fulfils the contract both
//! boards share ([`board_support::flavour::Flavour`]). Every task exists in every flavour;
//! one whose source a flavour lacks is never woken there (the DCMI's interrupts without a
//! camera, the host link's tasks without a host link, the link UART the flavour does not use).
//! So the app has no `cfg` but the flavour's selection.
//!
//! | RTIC task | prio | binds / trigger | body |
//! |---|---|---|---|
//! | `link_irq` / `link_irq_usart1` | 4 | link UART (UART4; USART1 in QEMU, `flavour::LinkUart`): RXNE, TXE | bytes into a lock-free queue (a full queue pauses the interrupt, see [`board_support::uart_rx`]); queued frames out ([`board_support::uart_tx`]); one [`board_support::uart_link`] |
//! | `uart_rx` | 3 | woken by `link_irq` | [`StereoBoardApp::on_rx_bytes`] (with the parameter sector on the real board) |
//! | `host_irq` / `host_rx` | 4 / 3 | USART2 RXNE (qemu) or IDLE (hil: received by DMA, [`board_support::uart_dma`]), TXE | [`StereoBoardApp::on_host_bytes`] (lockstep flavours; the real board has no host link); queued frames out |
//! | `host_dma` | 4 | DMA1 stream 5 (hil) | half/full buffer: pends `host_irq` |
//! | `dcmi_irq` | 4 | DCMI frame end, VSYNC, overrun, sync error (real) | checks the frame ([`stereo_board::camera::CaptureMonitor`]), hands a whole one on, re-arms after a torn one |
//! | `dma_irq` | 4 | DMA2 stream 1 transfer / direct-mode error (real) | counts, re-arms |
//! | `frame` | 2 | spawned per frame | [`StereoBoardApp::on_frame`] (the frame's buffer checked for a refill when processing ends) |
//! | `status` | 1 | every `app::STATUS_PERIOD` | capture state into [`StereoBoardApp::status_tick`], LED, watchdog |
//! | `idle` | 0 | nothing else to run | `WFI` (sleep until an interrupt) |
//!
//! Edge-FS runs inside a lock of the board state, whose ceiling is the receive tasks'
//! priority 3: while a frame is processed, received bytes wait in the queues filled at
//! priority 4 and are decoded right after. The gyro sample used for a frame is the latest one
//! when processing starts. Frames go out through [`board_support::uart_tx`]: a task copies a
//! whole frame into the UART's transmit queue (never waiting for the line; a full queue drops
//! the frame and counts it) and the UART's interrupt moves the bytes out, one per TXE.
//!
//! Time: on hardware the library sees the board clock. In the `hil` and `qemu` flavours it
//! sees the world time of the host's simulation (see [`lockstep`]). `status` stays on the board
//! clock.
//!
//! Parameters: at boot the Edge-FS parameters are the record saved in the parameter sector
//! ([`board_support::param_flash`], [`StereoBoardApp::load_params`]), or the defaults when there
//! is none or it is bad (logged, and answered to `ParamOp::Storage`). A save, passed on by the
//! autopilot only while its motors are off, erases and programs the sector in `uart_rx` with
//! the board lock held: the core stalls for the erase anyway (a second or two; no frame is
//! processed meanwhile), and the watchdog is given [`board_support::watchdog::SAVE`] for it
//! ([`board_support::param_flash::WatchedSector`], the autopilot's way too). The `qemu`
//! flavour has no parameter storage.
//!
//! Memory: the board state (Edge-FS history, decoders) is CPU-only and lives in CCM
//! ([`APP`]); camera frame buffers are DMA targets in SRAM. `cargo xtask size` prints the
//! static use.
//!
//! Flavours: `real` (the original board: camera on the DCMI, link on UART4), `hil` (the same
//! board, frames from a host on USART2) and `qemu` (`-M netduinoplus2`: no camera, link on
//! USART1 and host on USART2, the first two `-serial` ports; the flavour picks the link UART).

mod board;
mod clock;
#[cfg(any(feature = "qemu", feature = "hil"))]
#[path = "lockstep.rs"]
mod flavour;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
#[path = "real.rs"]
mod flavour;
mod pins;
use board_support::log;
use board_support::uart_link::{LinkInterrupt, LinkReader, UartLink};
use board_support::uart_tx::TxWriter;

use core::mem::MaybeUninit;
use core::sync::atomic::AtomicU32;
use defmt_rtt as _;

// Panic and HardFault: log, then wait for the watchdog (the camera board drives no actuator).
board_support::fault_handlers!(no_actuators);

/// The camera board's actuator stop for the fault path: it has none.
fn no_actuators() {}
use stereo_board::app::StereoBoardApp;

rtic_monotonics::systick_monotonic!(Mono, 1_000);

/// The board state: CPU-only, so it lives in CCM. The section is NOLOAD (not initialised by
/// the start-up code); `init` writes it before anything reads it.
#[link_section = ".ccmram"]
static mut APP: MaybeUninit<StereoBoardApp> = MaybeUninit::uninit();

/// Received bytes lost since boot: queue full, or a UART overrun/framing/noise error.
static RX_LOST: AtomicU32 = AtomicU32::new(0);

/// Frames lost since the frame task last looked (a frame ended while the task was busy).
static FRAMES_LOST: AtomicU32 = AtomicU32::new(0);

/// Bytes of each receive queue between the RX interrupt and its decoding task.
const RX_QUEUE: usize = 4096;

/// Bytes of each transmit queue: an estimate (25 Hz) and the status and heartbeat (1 Hz) are a
/// few dozen bytes each; at 115,200 Bd the line drains about 11 bytes per ms, so the queue
/// holds well over a second's worth of what the board sends.
const TX_QUEUE: usize = 1024;

/// Queues whole frames on a UART's transmit queue (see [`board_support::uart_tx`]).
fn queue_frame(tx: &mut TxWriter, frame: &[u8]) {
    // A full queue drops the frame and counts it (`TxWriter::dropped_frames`, in the log).
    let _ = tx.send(frame);
}

/// Queues whole frames on the host link's transmit queue, if the flavour has a host link.
fn queue_host(tx: &mut Option<TxWriter>, frame: &[u8]) {
    if let Some(tx) = tx {
        queue_frame(tx, frame);
    }
}

/// The host link's storage: its queues' sizes are the flavour's.
pub type HostStore = UartLink<{ flavour::HOST_QUEUE.0 }, { flavour::HOST_QUEUE.1 }>;

/// The host link's ends (lockstep flavours): its transmit queue, its interrupt's end, its
/// decoding task's end and the frame path.
pub type HostLink = (TxWriter, HostInterrupt, LinkReader, flavour::HostFrames);

/// The host link's interrupt end.
type HostInterrupt = LinkInterrupt<
    stm32f4xx_hal::pac::USART2,
    board_support::flavour::HostRx<stm32f4xx_hal::pac::USART2>,
>;

/// The frame task's view of its frame source (the flavour's `Frames`).
trait FrameSource {
    /// The frame and its exposure time.
    fn take(
        &mut self,
        ready: &flavour::FrameReady,
    ) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], timebase::Instant)>;
    /// True if the frame was not touched while it was being processed.
    fn intact(ready: &flavour::FrameReady) -> bool;
    /// Done with the frame (also one the frame task never took).
    fn release(ready: &flavour::FrameReady);
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3, UART5])]
mod app {
    use super::board::{self, LinkPort as _};
    use super::flavour::{self, Current as Flavour, FrameReady, Frames, LinkUart, HOST_QUEUE};
    use super::{clock, log, queue_frame, queue_host, FrameSource, HostInterrupt, Mono, APP};
    use super::{RX_LOST, RX_QUEUE, TX_QUEUE};
    use board_support::flavour::{Flavour as _, PARAM_STORAGE};
    use board_support::uart_link::{LinkInterrupt, LinkReader, UartLink};
    use board_support::uart_tx::TxWriter;
    use core::sync::atomic::Ordering;
    use rtic_monotonics::Timebase as _;
    use stereo_board::app::{StereoBoardApp, STATUS_PERIOD};
    use stereo_board::edge_fs::EdgeFsParams;
    use stm32f4xx_hal::{prelude::*, serial::Rx, watchdog::IndependentWatchdog};

    use board_support::param_flash::{ParamSector, WatchedSector};
    use stereo_board::app::{FrameOutcome, StereoFrame};
    use stereo_board::camera::CaptureMonitor;

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;

    /// The status task's period in ticks of `Mono` (1 kHz: a tick is a millisecond).
    const STATUS_TICKS: u32 = STATUS_PERIOD.as_millis() as u32;

    #[shared]
    struct Shared {
        board: &'static mut StereoBoardApp,
        /// The link's transmit queue (tasks' side).
        link_tx: TxWriter,
        /// The host link's transmit queue (qemu, hil flavours; the real board leaves its
        /// USART2 unused).
        host_tx: Option<TxWriter>,
        frames: Frames,
        /// The capture path's state (real flavour; idle in the others).
        capture: CaptureMonitor,
        /// The link's interrupt end (shared by the two link UART tasks, of which the
        /// flavour's link wakes one).
        link: LinkInterrupt<LinkUart, Rx<LinkUart>>,
        /// The watchdog: fed by `status`, given the save's timeout by `uart_rx` for a save.
        iwdg: IndependentWatchdog,
    }

    #[local]
    struct Local {
        /// The parameter sector (`None` in the `qemu` flavour).
        param_sector: Option<ParamSector>,
        /// The link's decoding task's end.
        link_reader: LinkReader,
        /// The host link's interrupt end (`None` in the real flavour).
        host: Option<HostInterrupt>,
        /// The host link's decoding task's end and frame path (`None` in the real flavour).
        host_reader: Option<(LinkReader, flavour::HostFrames)>,
    }

    #[init(local = [
        link_store: UartLink<RX_QUEUE, TX_QUEUE> = UartLink::new(),
        host_store: UartLink<{ HOST_QUEUE.0 }, { HOST_QUEUE.1 }> = UartLink::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // First: the status line's `stack_free` is the headroom left from here on.
        board_support::stack::paint();
        let mut rcc = cx.device.RCC.freeze(board::clocks());
        Mono::start(cx.core.SYST, board::SYSTICK_HZ);

        // SAFETY: `init` runs once, before any task; this is the only reference ever made to
        // APP, and it is handed to RTIC as a shared resource.
        #[allow(static_mut_refs)]
        let board_state: &'static mut StereoBoardApp =
            unsafe { APP.write(StereoBoardApp::new(EdgeFsParams::default_config())) };
        // The saved parameters, or the defaults and why (QEMU models no flash interface).
        let param_sector = PARAM_STORAGE.then(|| ParamSector::new(cx.device.FLASH));
        if let Some(sector) = &param_sector {
            match board_state.load_params(sector) {
                Ok(()) => log::info!("parameters: the saved record is in use"),
                Err(why) => defmt::warn!("parameters: defaults ({})", why),
            }
        }

        // The HAL's port split resets the port: split before the pin table is applied.
        let gpioa = cx.device.GPIOA.split(&mut rcc);
        let candidates = (
            (cx.device.UART4, (gpioa.pa0, gpioa.pa1)),
            (cx.device.USART1, (gpioa.pa9, gpioa.pa10)),
        );
        let (link_tx, mut link_rx) = LinkUart::open(candidates, &mut rcc).split();
        link_rx.listen();
        let (link_tx, link, link_reader) =
            cx.local
                .link_store
                .split(LinkUart::IRQ, link_tx, link_rx, &RX_LOST);

        // The host link: HIL frames in, estimates mirrored out (lockstep flavours).
        let host = flavour::host_link(
            cx.device.USART2,
            (gpioa.pa2, gpioa.pa3),
            &mut rcc,
            cx.local.host_store,
            &RX_LOST,
        );
        let (host_tx, host, host_reader) = match host {
            Some((tx, interrupt, reader, frames)) => {
                (Some(tx), Some(interrupt), Some((reader, frames)))
            }
            None => (None, None, None),
        };
        // The frame source: the cameras (real), or the host link's frame slot.
        let (frames, capture) = flavour::start_frames(cx.device.I2C2);

        let mut iwdg = IndependentWatchdog::new(cx.device.IWDG);
        board_support::watchdog::set(&mut iwdg, Flavour::WATCHDOG);

        log::info!("stereo-board up, sysclk {} Hz", rcc.clocks.sysclk().raw());
        status::spawn().ok();
        uart_rx::spawn().ok();
        host_rx::spawn().ok();

        (
            Shared {
                board: board_state,
                link_tx,
                host_tx,
                frames,
                capture,
                link,
                iwdg,
            },
            Local {
                param_sector,
                link_reader,
                host,
                host_reader,
            },
        )
    }

    /// Nothing to do: sleep until the next interrupt (RM0090 5.3.3, Sleep mode: the core
    /// stops, the peripherals, DMA and their interrupts run on). Without it the core spins, and
    /// an emulator has to execute every cycle instead of skipping to the next event.
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The link UART's interrupt, UART4 on the board: queued frames out, received bytes into
    /// the queue. A binding names its interrupt literally, so both of the flavours' link UARTs
    /// are bound (`link_irq_usart1`); the one the flavour's link does not use is never enabled.
    #[task(binds = UART4, priority = 4, shared = [link])]
    fn link_irq(mut cx: link_irq::Context) {
        cx.shared.link.lock(|link| link.serve());
    }

    /// The link UART's interrupt, USART1 on QEMU's machine (see `link_irq`).
    #[task(binds = USART1, priority = 4, shared = [link])]
    fn link_irq_usart1(mut cx: link_irq_usart1::Context) {
        cx.shared.link.lock(|link| link.serve());
    }

    /// Decodes the autopilot's bytes (gyro/attitude, config, parameter requests, heartbeat);
    /// a parameter save writes the parameter sector under the save's watchdog timeout.
    #[task(priority = 3, shared = [board, link_tx, iwdg], local = [link_reader, param_sector])]
    async fn uart_rx(mut cx: uart_rx::Context) {
        while cx.local.link_reader.woken().await {
            let mut buf = [0u8; 64];
            loop {
                let n = cx.local.link_reader.take(&mut buf);
                if n == 0 {
                    break;
                }
                let now = Flavour::lib_now();
                let bytes = buf.get(..n).unwrap_or(&[]);
                let sector = cx.local.param_sector.as_mut();
                let mut shared = (
                    &mut cx.shared.board,
                    &mut cx.shared.link_tx,
                    &mut cx.shared.iwdg,
                );
                shared.lock(|board, tx, watchdog| {
                    let mut tx = |frame: &[u8]| queue_frame(tx, frame);
                    match sector {
                        Some(sector) => {
                            let before = board.storage();
                            let mut store =
                                WatchedSector::new(&mut *sector, Flavour::WATCHDOG, |timeout| {
                                    board_support::watchdog::set(watchdog, timeout)
                                });
                            board.on_rx_bytes(bytes, now, &mut tx, Some(&mut store));
                            super::log_save(before, board.storage(), sector.last_error());
                        }
                        None => board.on_rx_bytes(bytes, now, &mut tx, None),
                    }
                    flavour::on_link_bytes(board);
                });
            }
        }
    }

    /// USART2 (host link: HIL frames in, estimates out) interrupt; never enabled in the real
    /// flavour.
    #[task(binds = USART2, priority = 4, local = [host])]
    fn host_irq(cx: host_irq::Context) {
        if let Some(host) = cx.local.host {
            host.serve();
        }
    }

    /// DMA1 stream 5 (hil; never enabled in the other flavours): the host link's receive
    /// buffer is half or wholly full; `host_irq` hands the bytes on.
    #[task(binds = DMA1_STREAM5, priority = 4)]
    fn host_dma(_: host_dma::Context) {
        board::HOST_RX_DMA.acknowledge();
        rtic::pend(stm32f4xx_hal::pac::Interrupt::USART2);
    }

    /// Decodes the host's bytes and assembles frame chunks into the frame slot
    /// (`flavour::HostFrames`); a completed frame wakes the frame task. Ends at once in the
    /// real flavour, which has no host link.
    #[task(priority = 3, shared = [board, frames], local = [host_reader])]
    async fn host_rx(mut cx: host_rx::Context) {
        let Some((link, host_frames)) = cx.local.host_reader.as_mut() else {
            return;
        };
        while link.woken().await {
            let mut buf = [0u8; 256];
            loop {
                let n = link.take(&mut buf);
                if n == 0 {
                    break;
                }
                let bytes = buf.get(..n).unwrap_or(&[]);
                let ready = (&mut cx.shared.board, &mut cx.shared.frames)
                    .lock(|board, frames| host_frames.on_bytes(board, frames, bytes));
                if let Some(ready) = ready {
                    frame::spawn(ready).ok();
                }
            }
        }
    }

    /// DCMI interrupt (frame end, VSYNC, overrun, sync error; real flavour, never enabled in
    /// the others): a whole frame goes to the frame task; one ending while the task is still
    /// busy is dropped and counted.
    #[task(binds = DCMI, priority = 4, shared = [capture])]
    fn dcmi_irq(mut cx: dcmi_irq::Context) {
        let now = clock::now();
        let ready = cx
            .shared
            .capture
            .lock(|m| flavour::on_dcmi_interrupt(m, now));
        if let Some(ready) = ready {
            if let Err(ready) = frame::spawn(ready) {
                Frames::release(&ready);
                super::FRAMES_LOST.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// DMA2 stream 1 (camera) error interrupt (real flavour, never enabled in the others).
    #[task(binds = DMA2_STREAM1, priority = 4, shared = [capture])]
    fn dma_irq(mut cx: dma_irq::Context) {
        cx.shared.capture.lock(flavour::on_dma_interrupt);
    }

    /// Edge-FS on the ready frame, then the estimate to the autopilot (and mirrored to the
    /// host link in the qemu and hil flavours). A frame whose buffer was refilled while it was
    /// processed sends nothing and clears the flow history.
    #[task(priority = 2, shared = [board, frames, link_tx, host_tx, capture])]
    async fn frame(mut cx: frame::Context, ready: FrameReady) {
        let start = Flavour::lib_now();
        let mut shared = (
            &mut cx.shared.board,
            &mut cx.shared.frames,
            &mut cx.shared.link_tx,
            &mut cx.shared.host_tx,
        );
        let outcome = shared.lock(|board, frames, tx, host_tx| {
            let lost = super::FRAMES_LOST.swap(0, Ordering::Relaxed);
            let frame = frames.take(&ready).map(|(pixels, capture)| StereoFrame {
                pixels,
                capture,
                start,
            });
            let finish = || {
                let intact = Frames::intact(&ready);
                Frames::release(&ready);
                intact.then(Flavour::lib_now)
            };
            board.on_frame(lost, frame, finish, &mut |f| queue_frame(tx, f), &mut |f| {
                queue_host(host_tx, f)
            })
        });
        if outcome == FrameOutcome::Discarded {
            cx.shared.capture.lock(|m| m.on_frame_overwritten());
        }
    }

    /// 1 Hz: capture state, status and heartbeat to the autopilot, LED, watchdog. A stopped
    /// camera is reported and capture re-armed.
    #[task(priority = 1, shared = [board, link_tx, host_tx, capture, iwdg])]
    async fn status(mut cx: status::Context) {
        loop {
            let now = clock::now();
            let camera = cx.shared.capture.lock(|m| flavour::check_camera(m, now));
            let mut shared = (
                &mut cx.shared.board,
                &mut cx.shared.link_tx,
                &mut cx.shared.host_tx,
            );
            let status = shared.lock(|board, tx, host_tx| {
                board.status_tick(now, camera, &mut |f| queue_frame(tx, f), &mut |f| {
                    queue_host(host_tx, f)
                })
            });
            super::pins::toggle(&stereo_board::board::LED);
            cx.shared.iwdg.lock(|w| w.feed());
            let tx_dropped = cx.shared.link_tx.lock(|tx| tx.dropped_frames());
            let (rx_ok, host_errors, gyro_age) = cx.shared.board.lock(|b| {
                (
                    b.link_frames_ok(),
                    b.host_link_errors(),
                    b.gyro_age(Flavour::lib_now())
                        .map_or(u64::MAX, |d| d.as_micros()),
                )
            });
            let c = status.capture;
            log::info!(
                "status uptime_ms={} frames={} dropped={} link_rx_ok={} link_errors={} host_errors={} host_crc={} host_too_long={} rx_lost={} link_tx_dropped={} gyro_age_us={} camera_stopped={} frames_complete={} frames_torn={} dcmi_overruns={} dcmi_errors={} dma_errors={} rearms={} frames_overwritten={} stack_free={}",
                status.uptime_ms,
                status.frames_processed,
                status.frames_dropped,
                rx_ok,
                status.link_errors.total(),
                host_errors.total(),
                host_errors.crc,
                host_errors.too_long,
                RX_LOST.load(Ordering::Relaxed),
                tx_dropped,
                gyro_age,
                status.camera_stopped,
                c.frames_complete,
                c.frames_torn,
                c.dcmi_overruns,
                c.dcmi_sync_errors,
                c.dma_errors,
                c.rearms,
                c.frames_overwritten,
                board_support::stack::free_bytes()
            );
            Mono::delay(Duration::from_ticks(STATUS_TICKS)).await;
        }
    }
}

/// The log line of a save, told from the storage's counters before and after a batch of
/// received bytes: saved, or not and why (the flash's error, if it refused).
fn log_save(
    before: Option<protocol::params::StorageStatus>,
    after: Option<protocol::params::StorageStatus>,
    flash: Option<board_support::param_flash::FlashError>,
) {
    let (Some(before), Some(after)) = (before, after) else {
        return;
    };
    if after.saves != before.saves {
        log::info!("parameters: saved");
    }
    if after.failed_saves != before.failed_saves {
        match flash {
            Some(e) => defmt::warn!("parameters: not saved (the flash refused: {})", e),
            None => defmt::warn!("parameters: not saved (SaveFailed: read back other bytes)"),
        }
    }
}
