//! RTIC 2 application of the autopilot firmware (thumbv7em-none-eabihf only).
//!
//! A thin shell: every task body is one call into the board's hardware-free logic.

mod board;
mod log;

use defmt_rtt as _;
#[cfg(not(feature = "qemu"))]
use panic_probe as _;

rtic_monotonics::systick_monotonic!(Mono, 1_000);

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3, UART4])]
mod app {
    use super::{board, log, Mono};
    use embedded_io::Write as _;
    use protocol::{AutopilotToStereo, Heartbeat, Message as _, Node};
    use rtic_monotonics::Timebase as _;
    use stm32f4xx_hal::{
        gpio::{Output, PC13},
        pac,
        prelude::*,
        serial::{self, Tx},
    };

    type Duration = <Mono as rtic_monotonics::Timebase>::Duration;

    #[shared]
    struct Shared {
        link_tx: Tx<pac::USART1>,
    }

    #[local]
    struct Local {
        led: PC13<Output>,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut rcc = cx.device.RCC.freeze(board::clocks());
        Mono::start(cx.core.SYST, board::SYSTICK_HZ);

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
        let (link_tx, _link_rx) = link.split();

        log::info!("autopilot up, sysclk {} Hz", rcc.clocks.sysclk().raw());
        heartbeat::spawn().ok();
        (Shared { link_tx }, Local { led })
    }

    /// 1 Hz heartbeat to the camera board, LED toggle.
    #[task(priority = 1, shared = [link_tx], local = [led])]
    async fn heartbeat(mut cx: heartbeat::Context) {
        loop {
            let uptime_ms = Mono::now().as_ticks();
            let msg = AutopilotToStereo::Heartbeat(Heartbeat::new(Node::Autopilot, uptime_ms));
            let mut buf = [0u8; AutopilotToStereo::MAX_FRAME_BYTES];
            if let Ok(n) = protocol::encode(&msg, &mut buf) {
                cx.shared.link_tx.lock(|tx| {
                    let _ = tx.write_all(buf.get(..n).unwrap_or(&[]));
                });
            }
            cx.local.led.toggle();
            log::info!("heartbeat {} ms", uptime_ms);
            Mono::delay(Duration::from_ticks(1000)).await;
        }
    }
}
