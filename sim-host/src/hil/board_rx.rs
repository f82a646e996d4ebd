//! A board's host link as received ([`BoardRx`]): a reader thread decodes its `BoardToHost`
//! messages into a channel and keeps the link's decoding error counts.

use super::relay::read_chunks;
use crate::transport::Link;
use protocol::{BoardToHost, BoardToHostDecoder, LinkErrorCounts};
use std::sync::atomic::AtomicBool;
use std::sync::mpsc::{self, Receiver};
use std::sync::{Arc, Mutex};

/// A reader thread decoding `BoardToHost` messages from a board into a channel.
pub(super) struct BoardRx {
    pub(super) rx: Receiver<BoardToHost>,
    errors: Arc<Mutex<LinkErrorCounts>>,
}

impl BoardRx {
    pub(super) fn start(link: Box<dyn Link>, stop: Arc<AtomicBool>) -> Self {
        let (tx, rx) = mpsc::channel();
        let errors = Arc::new(Mutex::new(LinkErrorCounts::default()));
        let errs = Arc::clone(&errors);
        let mut dec = BoardToHostDecoder::new_mid_stream();
        read_chunks(link, stop, move |bytes| {
            let mut open = true;
            dec.feed(bytes, |m| open &= tx.send(m).is_ok());
            *errs.lock().unwrap_or_else(|e| e.into_inner()) = dec.errors();
            open
        });
        Self { rx, errors }
    }

    pub(super) fn errors(&self) -> LinkErrorCounts {
        *self.errors.lock().unwrap_or_else(|e| e.into_inner())
    }
}
