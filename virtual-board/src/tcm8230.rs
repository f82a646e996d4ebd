//! The Toshiba TCM8230MD camera sensor on SCCB (the camera board's two cameras). Not modelled yet.
