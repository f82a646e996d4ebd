//! The camera board's CPLD that interleaves the two cameras' pixels onto the DCMI. Not modelled yet.
