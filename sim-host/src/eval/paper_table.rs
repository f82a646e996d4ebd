//! The paper's published per-take numbers (the result plots of the data set repository,
//! W = 8, H = 5, D = 15, FOV 60°) for the takes shipped with our copy of the data set:
//! Edge-FS and the Farnebäck baseline, NMXM / MSE / VAR for x (forward) and y (sideways).

/// One row of published numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperRow {
    /// Board number.
    pub board: u32,
    /// Take number.
    pub take: u32,
    /// Edge-FS `[nmxm_x, mse_x, var_x, nmxm_y, mse_y, var_y]`.
    pub edgefs: [f64; 6],
    /// Farnebäck, same order.
    pub farneback: [f64; 6],
}

const fn row(board: u32, take: u32, v: [f64; 12]) -> PaperRow {
    PaperRow {
        board,
        take,
        edgefs: [v[0], v[2], v[4], v[6], v[8], v[10]],
        farneback: [v[1], v[3], v[5], v[7], v[9], v[11]],
    }
}

/// Published numbers (columns interleaved Edge-FS, Farnebäck as in the paper's plots).
pub const PAPER_TABLE: &[PaperRow] = &[
    row(
        1,
        1,
        [
            0.5695, 0.7850, 0.0741, 0.1460, 0.0494, 0.0942, 0.5020, 0.2915, 0.0022, 0.0128, 0.0012,
            0.0076,
        ],
    ),
    row(
        1,
        3,
        [
            0.8551, 0.7949, 0.0401, 0.0801, 0.0235, 0.0506, 0.3252, 0.3783, 0.0011, 0.0087, 0.0005,
            0.0061,
        ],
    ),
    row(
        1,
        5,
        [
            0.7342, 0.9170, 0.0739, 0.0516, 0.0583, 0.0362, 0.2451, 0.4537, 0.0013, 0.0038, 0.0008,
            0.0026,
        ],
    ),
    row(
        1,
        7,
        [
            0.8903, 0.7220, 0.0143, 0.0747, 0.0079, 0.0623, 0.3361, 0.4217, 0.0010, 0.0169, 0.0005,
            0.0144,
        ],
    ),
    row(
        1,
        9,
        [
            0.2265, 0.3275, 0.3897, 0.0399, 0.2624, 0.0209, 0.8865, 0.9148, 0.0174, 0.0101, 0.0076,
            0.0046,
        ],
    ),
    row(
        1,
        11,
        [
            0.4163, 0.3649, 0.0231, 0.0144, 0.0120, 0.0084, 0.7701, 0.7321, 0.0148, 0.0202, 0.0118,
            0.0148,
        ],
    ),
    row(
        1,
        13,
        [
            0.3939, 0.6302, 0.0872, 0.0054, 0.0500, 0.0025, 0.8998, 0.9104, 0.0056, 0.0054, 0.0022,
            0.0024,
        ],
    ),
    row(
        1,
        15,
        [
            0.2571, 0.4051, 0.5374, 0.6681, 0.3080, 0.4803, 0.6448, 0.4278, 0.0364, 0.1189, 0.0229,
            0.0830,
        ],
    ),
    row(
        1,
        17,
        [
            0.6332, 0.4649, 0.0145, 0.0086, 0.0075, 0.0054, 0.9183, 0.7978, 0.0031, 0.0126, 0.0016,
            0.0072,
        ],
    ),
    row(
        1,
        19,
        [
            0.9486, 0.9542, 0.0106, 0.0076, 0.0052, 0.0041, 0.5498, 0.6610, 0.0027, 0.0044, 0.0012,
            0.0019,
        ],
    ),
    row(
        1,
        21,
        [
            0.8946, 0.9387, 0.0091, 0.0084, 0.0045, 0.0053, 0.4944, 0.4600, 0.0010, 0.0011, 0.0005,
            0.0004,
        ],
    ),
    row(
        2,
        3,
        [
            0.7986, 0.6228, 0.1101, 0.3934, 0.0430, 0.1858, 0.2397, 0.3047, 0.0021, 0.0512, 0.0012,
            0.0340,
        ],
    ),
];

/// The published row of a take, if any.
pub fn paper_row(board: u32, take: u32) -> Option<&'static PaperRow> {
    PAPER_TABLE
        .iter()
        .find(|r| r.board == board && r.take == take)
}
