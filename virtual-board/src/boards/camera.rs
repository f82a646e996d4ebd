//! The camera board (TU Delft stereoboard, STM32F407). Not wired yet.
