//! `ndr keygen`: a certificate pair for a lab setup.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct KeygenArgs {
    /// Directory to write NAME.crt and NAME.key into (created if needed).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// The certificate's name (also its file names), e.g. base or remote.
    #[arg(long, default_value = "ndr")]
    pub name: String,
}

pub fn run(args: &KeygenArgs) -> Result<(), String> {
    let pair = ndr::keygen::write(&args.out, &args.name)?;
    println!("certificate: {}", pair.cert.display());
    println!("key:         {}", pair.key.display());
    println!("sha256:      {}", pair.fingerprint);
    eprintln!(
        "give {} to the peer (--peer-cert), or its fingerprint (--pin); keep the key here",
        pair.cert.display()
    );
    Ok(())
}
