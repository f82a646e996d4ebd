//! `cargo xtask`: project orchestration (CI test run, firmware builds and sizes, QEMU, instruction counts).

fn main() -> anyhow::Result<()> {
    anyhow::bail!("no xtask commands yet")
}
