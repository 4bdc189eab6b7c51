// Used by the dashboard and plot output, which the CLI does not wire up yet.
#[cfg_attr(not(test), allow(dead_code))]
mod draw;

fn main(){}
