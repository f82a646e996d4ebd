//! The boards' link line settings: one value, in `board_support::link`, that both board
//! definitions (and so both firmwares) take, so that a faster link is a one-line change.

#[test]
fn both_boards_take_the_one_link_baud_rate() {
    assert_eq!(
        board_support::link::LINK_BAUD,
        115_200,
        "the original harness's rate"
    );
    assert_eq!(
        stereo_board::board::LINK_BAUD,
        board_support::link::LINK_BAUD
    );
    assert_eq!(autopilot::board::LINK_BAUD, board_support::link::LINK_BAUD);
}
