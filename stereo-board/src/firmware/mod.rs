//! RTIC 2 application of the stereo-board firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell around [`stereo_board::app`]: the tasks below mirror `app::TASKS` and each body
//! is one call into [`StereoBoardApp`].
//!
//! | RTIC task | prio | binds / trigger | body |
//! |---|---|---|---|
//! | `usart1` | 4 | USART1 IDLE + DMA2 stream 2 (QEMU: RXNE) | bytes into a lock-free queue (never waits for a lock; in QEMU a full queue pauses the interrupt, see [`board_support::uart_rx`]) |
//! | `uart_rx` | 3 | woken by `usart1` | [`StereoBoardApp::on_rx_bytes`] |
//! | `usart2` / `host_rx` | 4 / 3 | USART2 RXNE (qemu, hil; back-pressure as for `usart1`) | [`StereoBoardApp::on_host_bytes`] |
//! | `dcmi_frame` | 4 | DMA2 stream 1 transfer complete (real) | hands the filled buffer on |
//! | `frame` | 2 | spawned per frame | [`StereoBoardApp::process_frame`] + `send_estimate` |
//! | `status` | 1 | every `app::STATUS_PERIOD_US` | [`StereoBoardApp::status_tick`], host heartbeat, LED, watchdog |
//!
//! Edge-FS runs inside a lock of the board state, whose ceiling is the receive tasks'
//! priority 3: while a frame is processed, received bytes wait in the queues filled at
//! priority 4 (4 KiB each, 44 ms of a 921,600 Bd line) and are decoded right after. The
//! gyro sample used for a frame is the latest one when processing starts.
//!
//! Time: on hardware the library sees the board clock. In the `hil` and `qemu` flavours it
//! sees the world time of the host's simulation ([`clock::lib_now_us`]): frames carry their
//! exposure time in world time and the autopilot, which runs in lockstep with the host, stamps
//! its gyro samples with world time, so gyro ages and processing times are measured on one
//! clock however slowly the link lets the world run. `status` stays on the board clock.
//!
//! Memory: the board state (Edge-FS history, decoders) is CPU-only and lives in CCM
//! ([`APP`]); camera frame buffers are DMA targets in SRAM. `cargo xtask size` prints the
//! static use.

mod board;
mod clock;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
mod dcmi;
use board_support::log;
#[cfg(not(any(feature = "qemu", feature = "hil")))]
mod sensor;
#[cfg(not(feature = "qemu"))]
use board_support::uart_dma;

use core::mem::MaybeUninit;
use defmt_rtt as _;
#[cfg(not(feature = "qemu"))]
use panic_probe as _;
use stereo_board::app::StereoBoardApp;

rtic_monotonics::systick_monotonic!(Mono, 1_000);

/// The board state: CPU-only, so it lives in CCM. The section is NOLOAD (not initialised by
/// the start-up code); `init` writes it before anything reads it.
#[link_section = ".ccmram"]
static mut APP: MaybeUninit<StereoBoardApp> = MaybeUninit::uninit();

/// Received bytes lost since boot: queue full, or a UART overrun/framing/noise error.
static RX_LOST: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Bytes of each receive queue between the RX interrupt and its decoding task.
const RX_QUEUE: usize = 4096;

/// Back-pressure of the host link's RXNE interrupt (qemu, hil flavours).
#[cfg(any(feature = "qemu", feature = "hil"))]
static HOST_FLOW: board_support::uart_rx::RxFlow =
    board_support::uart_rx::RxFlow::new(stm32f4xx_hal::pac::Interrupt::USART2);

/// Blocking write of whole frames to a UART (a few dozen bytes per message at 921,600 Bd).
fn write_all<U: stm32f4xx_hal::serial::Instance>(
    tx: &mut stm32f4xx_hal::serial::Tx<U>,
    bytes: &[u8],
) {
    use embedded_io::Write as _;
    let _ = tx.write_all(bytes);
}

#[cfg(any(feature = "qemu", feature = "hil"))]
/// A frame handed from the host-link task to the frame task (qemu, hil flavours): the
/// buffer and its exposure time (`None`: empty).
pub struct FrameSlot {
    buf: [u8; protocol::STEREO_FRAME_BYTES],
    capture_us: Option<u64>,
}

#[cfg(any(feature = "qemu", feature = "hil"))]
impl FrameSlot {
    const fn new() -> Self {
        Self {
            buf: [0; protocol::STEREO_FRAME_BYTES],
            capture_us: None,
        }
    }
}

/// The HIL frame slot (SRAM).
#[cfg(any(feature = "qemu", feature = "hil"))]
static mut SLOT: FrameSlot = FrameSlot::new();

/// The HIL frame assembler (SRAM).
#[cfg(any(feature = "qemu", feature = "hil"))]
static mut ASSEMBLER: stereo_board::app::FrameAssembler = stereo_board::app::FrameAssembler::new();

/// The camera's double buffer (real flavour; the buffers themselves live in [`dcmi`]).
#[cfg(not(any(feature = "qemu", feature = "hil")))]
pub struct Camera;

/// Where the frame task finds its frame.
#[cfg(any(feature = "qemu", feature = "hil"))]
type Frames = &'static mut FrameSlot;
/// Where the frame task finds its frame.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
type Frames = Camera;

/// What the frame task is spawned with.
#[cfg(any(feature = "qemu", feature = "hil"))]
type FrameReady = ();
/// What the frame task is spawned with: DMA buffer index and end-of-read-out time, µs.
#[cfg(not(any(feature = "qemu", feature = "hil")))]
type FrameReady = (usize, u64);

/// The frame task's view of its frame source.
trait FrameSource {
    /// The frame and its exposure time, µs.
    fn take(&mut self, ready: FrameReady) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)>;
    /// Done with the frame.
    fn release(&mut self, ready: FrameReady);
    /// Frames the source lost since the last call.
    fn dropped_since_last(&mut self) -> u32;
}

#[cfg(any(feature = "qemu", feature = "hil"))]
impl FrameSource for &'static mut FrameSlot {
    fn take(&mut self, _: ()) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)> {
        let capture = self.capture_us.take()?;
        Some((&self.buf, capture))
    }
    fn release(&mut self, _: ()) {}
    fn dropped_since_last(&mut self) -> u32 {
        0
    }
}

#[cfg(not(any(feature = "qemu", feature = "hil")))]
impl FrameSource for Camera {
    fn take(&mut self, ready: FrameReady) -> Option<(&[u8; protocol::STEREO_FRAME_BYTES], u64)> {
        dcmi::frame(ready.0).map(|f| (f, ready.1))
    }
    fn release(&mut self, ready: FrameReady) {
        dcmi::release(ready.0);
    }
    fn dropped_since_last(&mut self) -> u32 {
        dcmi::DROPPED.swap(0, core::sync::atomic::Ordering::Relaxed)
    }
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3, UART4, UART5])]
mod app {
    use super::{board, clock, log, write_all, FrameSource as _, Mono, APP, RX_QUEUE};
    use heapless::spsc::{Consumer, Producer, Queue};
    use rtic_monotonics::Timebase as _;
    use rtic_sync::channel::{Receiver, Sender};
    use stereo_board::app::{StereoBoardApp, STATUS_PERIOD_US};
    use stereo_board::edge_fs::EdgeFsParams;
    use stm32f4xx_hal::{
        gpio::{Output, PC13},
        pac,
        prelude::*,
        serial::{self, Rx, Tx},
        watchdog::IndependentWatchdog,
    };

    use super::{FrameReady, Frames};
    use board_support::uart_rx::LINK_FLOW;
    use protocol::BoardToHost;
    use stereo_board::app::{send_to_host, FrameAssembler};

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;
    type Wake = ();

    #[shared]
    struct Shared {
        board: &'static mut StereoBoardApp,
        link_tx: Tx<pac::USART1>,
        host_tx: Tx<pac::USART2>,
        frames: Frames,
        link_in: Producer<'static, u8>,
        link_wake_tx: Sender<'static, Wake, 1>,
    }

    #[local]
    struct Local {
        led: PC13<Output>,
        iwdg: IndependentWatchdog,
        link_rx: Rx<pac::USART1>,
        link_out: Consumer<'static, u8>,
        link_wake_rx: Receiver<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_rx: Rx<pac::USART2>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_in: Producer<'static, u8>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_out: Consumer<'static, u8>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_wake_tx: Sender<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_wake_rx: Receiver<'static, Wake, 1>,
        #[cfg(any(feature = "qemu", feature = "hil"))]
        assembler: &'static mut FrameAssembler,
    }

    #[init(local = [
        link_q: Queue<u8, RX_QUEUE> = Queue::new(),
        host_q: Queue<u8, RX_QUEUE> = Queue::new(),
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

        let gpioa = cx.device.GPIOA.split(&mut rcc);
        let gpioc = cx.device.GPIOC.split(&mut rcc);
        let led = gpioc.pc13.into_push_pull_output();

        let link = cx
            .device
            .USART1
            .serial::<u8>(
                (gpioa.pa9, gpioa.pa10),
                serial::Config::default().baudrate(board::LINK_BAUD.bps()),
                &mut rcc,
            )
            .unwrap_or_else(|_| log::fatal("USART1 configuration"));
        let (link_tx, link_rx) = link.split();
        #[cfg(feature = "qemu")]
        let link_rx = {
            let mut rx = link_rx;
            rx.listen();
            rx
        };
        #[cfg(not(feature = "qemu"))]
        super::uart_dma::start();
        let (link_in, link_out) = cx.local.link_q.split();
        let (link_wake_tx, link_wake_rx) = rtic_sync::make_channel!(Wake, 1);

        // The host link: HIL frames in (qemu, hil flavours); estimates mirrored out (all).
        let (host_tx, mut host_rx) = cx
            .device
            .USART2
            .serial::<u8>(
                (gpioa.pa2, gpioa.pa3),
                serial::Config::default().baudrate(board::LINK_BAUD.bps()),
                &mut rcc,
            )
            .unwrap_or_else(|_| log::fatal("USART2 configuration"))
            .split();
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_rx.listen();
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let _ = &mut host_rx;
        #[cfg(any(feature = "qemu", feature = "hil"))]
        // SAFETY: `init` runs once; these are the only references to the two statics.
        #[allow(static_mut_refs)]
        let (frames, assembler): (Frames, &'static mut FrameAssembler) = unsafe {
            (
                &mut *core::ptr::addr_of_mut!(super::SLOT),
                &mut *core::ptr::addr_of_mut!(super::ASSEMBLER),
            )
        };
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let frames: Frames = super::Camera;
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let (host_in, host_out) = cx.local.host_q.split();
        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        let _ = (cx.local.host_q, host_rx);
        #[cfg(any(feature = "qemu", feature = "hil"))]
        let (host_wake_tx, host_wake_rx) = rtic_sync::make_channel!(Wake, 1);

        #[cfg(not(any(feature = "qemu", feature = "hil")))]
        {
            use super::sensor::{CameraSensor as _, Tcm8230};
            let gpiob = cx.device.GPIOB.split(&mut rcc);
            let gpioe = cx.device.GPIOE.split(&mut rcc);
            let pins = super::dcmi::Pins {
                hsync: gpioa.pa4.into_alternate(),
                pixclk: gpioa.pa6.into_alternate(),
                vsync: gpiob.pb7.into_alternate(),
                d0: gpioc.pc6.into_alternate(),
                d1: gpioc.pc7.into_alternate(),
                d2: gpioc.pc8.into_alternate(),
                d3: gpioc.pc9.into_alternate(),
                d4: gpioc.pc11.into_alternate(),
                d5: gpiob.pb6.into_alternate(),
                d6: gpioe.pe5.into_alternate(),
                d7: gpioe.pe6.into_alternate(),
                xclk: gpioa.pa8.into_alternate(),
            };
            let polarity = super::dcmi::Polarity {
                pixclk_rising: true,
                hsync_high: false,
                vsync_high: false,
            };
            // The camera clock (MCO1) must run before the sensor answers on the bus.
            super::dcmi::start(cx.device.DCMI, cx.device.DMA2, pins, polarity);
            let mut sccb = cx.device.I2C2.i2c(
                (gpiob.pb10, gpiob.pb11),
                stm32f4xx_hal::i2c::Mode::standard(100.kHz()),
                &mut rcc,
            );
            let format = Tcm8230::INIT.last().map(|&(reg, value)| (reg, value));
            let answer = Tcm8230.init(&mut sccb).and_then(|()| match format {
                Some((reg, _)) => Tcm8230.read(&mut sccb, reg).map(Some),
                None => Ok(None),
            });
            match (answer, format) {
                (Ok(read), Some((_, written))) if read == Some(written) => {
                    log::info!("camera configured")
                }
                _ => defmt::error!("camera sensor did not answer on SCCB"),
            }
        }

        let mut iwdg = IndependentWatchdog::new(cx.device.IWDG);
        iwdg.start(board::WATCHDOG_MS.millis());

        log::info!("stereo-board up, sysclk {} Hz", rcc.clocks.sysclk().raw());
        status::spawn().ok();
        uart_rx::spawn().ok();
        #[cfg(any(feature = "qemu", feature = "hil"))]
        host_rx::spawn().ok();

        (
            Shared {
                board: board_state,
                link_tx,
                host_tx,
                frames,
                link_in,
                link_wake_tx,
            },
            Local {
                led,
                iwdg,
                link_rx,
                link_out,
                link_wake_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_in,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_out,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_wake_tx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                host_wake_rx,
                #[cfg(any(feature = "qemu", feature = "hil"))]
                assembler,
            },
        )
    }

    /// USART1 (autopilot link) receive interrupt: RXNE in QEMU, IDLE line with DMA otherwise.
    #[task(binds = USART1, priority = 4, shared = [link_in, link_wake_tx], local = [link_rx])]
    fn usart1(cx: usart1::Context) {
        let rx = cx.local.link_rx;
        (cx.shared.link_in, cx.shared.link_wake_tx).lock(|queue, wake| {
            #[cfg(feature = "qemu")]
            {
                board_support::uart_rx::drain(rx, queue, &LINK_FLOW, &super::RX_LOST);
                let _ = wake.try_send(());
            }
            #[cfg(not(feature = "qemu"))]
            {
                let _ = rx;
                let lost = super::uart_dma::on_interrupt(queue);
                super::RX_LOST.fetch_add(lost, core::sync::atomic::Ordering::Relaxed);
                let _ = wake.try_send(());
            }
        });
    }

    /// DMA2 stream 2 (USART1 RX) half/full transfer: hand on what arrived so far.
    #[cfg(not(feature = "qemu"))]
    #[task(binds = DMA2_STREAM2, priority = 4, shared = [link_in, link_wake_tx])]
    fn usart1_dma(cx: usart1_dma::Context) {
        (cx.shared.link_in, cx.shared.link_wake_tx).lock(|queue, wake| {
            let lost = super::uart_dma::on_interrupt(queue);
            super::RX_LOST.fetch_add(lost, core::sync::atomic::Ordering::Relaxed);
            let _ = wake.try_send(());
        });
    }

    /// Decodes the autopilot's bytes (gyro/attitude, config, heartbeat).
    #[task(priority = 3, shared = [board, link_tx], local = [link_out, link_wake_rx])]
    async fn uart_rx(mut cx: uart_rx::Context) {
        loop {
            if cx.local.link_wake_rx.recv().await.is_err() {
                return;
            }
            let mut buf = [0u8; 64];
            loop {
                let n = LINK_FLOW.take(cx.local.link_out, &mut buf);
                if n == 0 {
                    break;
                }
                let now = clock::lib_now_us();
                let bytes = buf.get(..n).unwrap_or(&[]);
                (&mut cx.shared.board, &mut cx.shared.link_tx).lock(|board, tx| {
                    board.on_rx_bytes(bytes, now, &mut |frame| write_all(tx, frame));
                    // Lockstep flavours: the autopilot's gyro timestamps are world time.
                    #[cfg(any(feature = "qemu", feature = "hil"))]
                    if let Some(g) = board.latest_gyro() {
                        clock::observe_world_gyro(g.timestamp_us);
                    }
                });
            }
        }
    }

    /// USART2 (host link: HIL frames in) receive interrupt.
    #[cfg(any(feature = "qemu", feature = "hil"))]
    #[task(binds = USART2, priority = 4, local = [host_rx, host_in, host_wake_tx])]
    fn usart2(cx: usart2::Context) {
        board_support::uart_rx::drain(
            cx.local.host_rx,
            cx.local.host_in,
            &super::HOST_FLOW,
            &super::RX_LOST,
        );
        let _ = cx.local.host_wake_tx.try_send(());
    }

    /// Decodes the host's bytes and assembles frame chunks; a completed frame goes to the
    /// frame slot (replacing, and counting as dropped, one that was not processed yet).
    #[cfg(any(feature = "qemu", feature = "hil"))]
    #[task(priority = 3, shared = [board, frames], local = [host_out, host_wake_rx, assembler])]
    async fn host_rx(mut cx: host_rx::Context) {
        loop {
            if cx.local.host_wake_rx.recv().await.is_err() {
                return;
            }
            let mut buf = [0u8; 256];
            loop {
                let n = super::HOST_FLOW.take(cx.local.host_out, &mut buf);
                if n == 0 {
                    break;
                }
                let bytes = buf.get(..n).unwrap_or(&[]);
                let assembler = &mut *cx.local.assembler;
                let ready = (&mut cx.shared.board, &mut cx.shared.frames).lock(|board, slot| {
                    let mut ready = false;
                    let mut overwritten = 0u32;
                    board.on_host_bytes(bytes, assembler, |frame, capture_us| {
                        if slot.capture_us.is_some() {
                            overwritten += 1;
                        }
                        slot.buf.copy_from_slice(frame);
                        slot.capture_us = Some(capture_us);
                        clock::observe_world_us(capture_us);
                        ready = true;
                    });
                    for _ in 0..overwritten {
                        board.frame_dropped();
                    }
                    ready
                });
                if ready {
                    frame::spawn(()).ok();
                }
            }
        }
    }

    /// Camera frame complete (DMA2 stream 1, DCMI): the filled half of the double buffer goes
    /// to the frame task; a frame arriving while the previous one is still waiting is dropped
    /// and counted.
    #[cfg(not(any(feature = "qemu", feature = "hil")))]
    #[task(binds = DMA2_STREAM1, priority = 4)]
    fn dcmi_frame(_cx: dcmi_frame::Context) {
        if let Some(ready) = super::dcmi::on_transfer_complete(clock::now_us()) {
            if frame::spawn(ready).is_err() {
                super::dcmi::release(ready.0);
                super::dcmi::DROPPED.fetch_add(1, core::sync::atomic::Ordering::Relaxed);
            }
        }
    }

    /// Edge-FS on the ready frame, then the estimate to the autopilot (and mirrored to the
    /// host link).
    #[task(priority = 2, shared = [board, frames, link_tx, host_tx])]
    async fn frame(mut cx: frame::Context, ready: FrameReady) {
        let start = clock::lib_now_us();
        let est = (
            &mut cx.shared.board,
            &mut cx.shared.frames,
            &mut cx.shared.link_tx,
        )
            .lock(|board, frames, tx| {
                for _ in 0..frames.dropped_since_last() {
                    board.frame_dropped();
                }
                let (out, capture_us) = {
                    let (buf, capture_us) = frames.take(ready)?;
                    (board.process_frame(buf, capture_us, start), capture_us)
                };
                frames.release(ready);
                let done = clock::lib_now_us();
                Some(board.send_estimate(&out, capture_us, done, &mut |f| write_all(tx, f)))
            });
        if let Some(est) = est {
            cx.shared.host_tx.lock(|tx| {
                send_to_host(&BoardToHost::Estimate(est), &mut |f| write_all(tx, f));
            });
        }
    }

    /// 1 Hz: status and heartbeat to the autopilot, LED, watchdog.
    #[task(priority = 1, shared = [board, link_tx, host_tx], local = [led, iwdg])]
    async fn status(mut cx: status::Context) {
        loop {
            let now = clock::now_us();
            let status = (&mut cx.shared.board, &mut cx.shared.link_tx)
                .lock(|board, tx| board.status_tick(now, &mut |f| write_all(tx, f)));
            // The host link gets a heartbeat too: a HIL host starts streaming once it sees one
            // (bytes sent before the USART is enabled are lost).
            let hb = protocol::Heartbeat::new(protocol::Node::StereoBoard, status.uptime_ms);
            cx.shared.host_tx.lock(|tx| {
                send_to_host(&BoardToHost::Heartbeat(hb), &mut |f| write_all(tx, f));
            });
            cx.local.led.toggle();
            cx.local.iwdg.feed();
            let (rx_ok, host_errors, gyro_age) = cx.shared.board.lock(|b| {
                (
                    b.link_frames_ok(),
                    b.host_link_errors(),
                    b.gyro_age_us(clock::lib_now_us()).unwrap_or(u64::MAX),
                )
            });
            log::info!(
                "status uptime_ms={} frames={} dropped={} link_rx_ok={} link_errors={} host_errors={} host_crc={} host_too_long={} rx_lost={} gyro_age_us={} stack_free={}",
                status.uptime_ms,
                status.frames_processed,
                status.frames_dropped,
                rx_ok,
                status.link_errors.total(),
                host_errors.total(),
                host_errors.crc,
                host_errors.too_long,
                super::RX_LOST.load(core::sync::atomic::Ordering::Relaxed),
                gyro_age,
                board_support::stack::free_bytes()
            );
            Mono::delay(Duration::from_ticks(STATUS_PERIOD_US / 1_000)).await;
        }
    }
}
