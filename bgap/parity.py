from bgap.runner.numerics import command

main = command("bgap.experiments.parity")
if __name__ == "__main__":
    main()
