from rmbuild.cli import main

main()
